"""Samples stored twice (two replicas) are read once, through the HTTP telemetry views.

With several replicas a vehicle that moves from replica A to replica B within
FLEET_BUCKET_MAX_AGE_S may have samples stored by both: A writes the bucket it
still held, B had stored the vehicle's resend (docs/live.md, "Several
replicas"). Here one app is the replica the vehicle talks to, and a bucket
inserted through that app's telemetry repository stands for the other
replica's write of the same samples. The other replica's copies carry another
``battery_pct``, so a test sees which copy a view shows: the first stored.
"""

from __future__ import annotations

import csv
import io
import xml.etree.ElementTree as ET
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from typing import Any

import httpx
import pytest
from asgi_lifespan import LifespanManager

from fleet_protocol import Sample
from server.app import create_app
from server.services.telemetry import TelemetryService
from server.settings import Settings
from server.storage.telemetry import TelemetryRepo
from tests.factories import ADMIN, make_vehicle, sample, start_instance

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")

OURS = 80.0  # battery_pct of the samples the vehicle sends to this app
THEIRS = 11.0  # battery_pct of the other replica's copies
WINDOW = {"from": "2026-11-22T09:00:00.000Z", "to": "2026-11-22T11:00:00.000Z"}


def _sample(seq: int, battery_pct: float) -> dict[str, Any]:
    """Sample ``seq`` on a zigzag (every point counts in a downsampled track)."""
    return sample(seq, lat=43.9 + seq * 1e-4, lon=15.4 + (seq % 2) * 1e-4, battery_pct=battery_pct)


class Replica:
    def __init__(self, http: httpx.AsyncClient, telemetry: TelemetryService) -> None:
        self.http = http
        self.telemetry = telemetry

    async def vehicle(self) -> tuple[str, dict[str, str], str]:
        vehicle_id, headers = await make_vehicle(self.http)
        instance_id = (await start_instance(self.http, vehicle_id, headers))["instance_id"]
        return vehicle_id, headers, instance_id

    async def send(self, headers: dict[str, str], instance_id: str, seqs: range) -> int:
        r = await self.http.post(
            "/upper/update_param",
            headers=headers,
            json={"instance_id": instance_id, "samples": [_sample(n, OURS) for n in seqs]},
        )
        assert r.status_code == 200, r.text
        accepted: int = r.json()["accepted"]
        return accepted

    async def other_replica_writes(self, vehicle_id: str, seqs: range) -> None:
        """The other replica's bucket of samples ``seqs`` (its copies say THEIRS)."""
        copies = [Sample.model_validate(_sample(n, THEIRS)) for n in seqs]
        docs = [s.model_dump(exclude_none=True) for s in copies]
        await self.telemetry.repo.insert(TelemetryRepo.make_bucket(vehicle_id, docs))

    async def view(self, vehicle_id: str, view: str, **params: Any) -> httpx.Response:
        r = await self.http.get(f"/api/vehicles/{vehicle_id}/{view}", headers=ADMIN, params=params)
        assert r.status_code == 200, r.text
        return r

    async def csv_seqs(self, vehicle_id: str) -> list[int]:
        r = await self.view(vehicle_id, "track", **WINDOW, format="csv")
        return [int(row["seq"]) for row in csv.DictReader(io.StringIO(r.text))]

    async def paged(self, vehicle_id: str, limit: int) -> list[dict[str, Any]]:
        """Every stored sample, one page of ``limit`` after another."""
        out: list[dict[str, Any]] = []
        after: int | None = -1
        while after is not None:
            page = (await self.view(vehicle_id, "telemetry", after_seq=after, limit=limit)).json()
            out += page["samples"]
            after = page["next_after_seq"]
        return out


@asynccontextmanager
async def replica(make_settings: Callable[..., Settings]) -> AsyncIterator[Replica]:
    # Five samples to a bucket: a batch of ten is written while its call is answered.
    app = create_app(make_settings(bucket_samples=5, bucket_max_age_s=60))
    async with LifespanManager(app) as manager:
        transport = httpx.ASGITransport(app=manager.app)
        async with httpx.AsyncClient(transport=transport, base_url="http://test") as http:
            yield Replica(http, app.state.services.telemetry)


def batteries(points: list[dict[str, Any]]) -> dict[int, float]:
    return {p["seq"]: p["battery_pct"] for p in points}


async def test_a_late_second_copy_is_not_shown(make_settings: Callable[..., Settings]) -> None:
    """The other replica writes its copies of 4..9 after this one wrote 1..10 (11, 12 unwritten)."""
    async with replica(make_settings) as app:
        vid, vh, iid = await app.vehicle()
        assert await app.send(vh, iid, range(1, 13)) == 12
        await app.other_replica_writes(vid, range(4, 10))
        every = list(range(1, 13))
        ours = dict.fromkeys(every, OURS)

        for limit in (100, 5, 3, 1):
            samples = await app.paged(vid, limit)
            assert [s["seq"] for s in samples] == every, limit
            assert batteries(samples) == ours
        page = (await app.view(vid, "telemetry", after_seq=5, limit=3)).json()
        assert [s["seq"] for s in page["samples"]] == [6, 7, 8]

        track = (await app.view(vid, "track", **WINDOW)).json()
        assert [p["seq"] for p in track["points"]] == every
        assert batteries(track["points"]) == ours
        fewer = (await app.view(vid, "track", **WINDOW, max_points=50)).json()
        assert [p["seq"] for p in fewer["points"]] == every

        geo = (await app.view(vid, "track", **WINDOW, format="geojson")).json()
        assert len(geo["geometry"]["coordinates"]) == len(geo["properties"]["times"]) == 12
        gpx = await app.view(vid, "track", **WINDOW, format="gpx")
        ns = {"g": "http://www.topografix.com/GPX/1/1"}
        assert len(ET.fromstring(gpx.content).findall(".//g:trkpt", ns)) == 12
        assert await app.csv_seqs(vid) == every


async def test_the_copy_stored_first_is_the_one_shown(
    make_settings: Callable[..., Settings],
) -> None:
    """The other replica writes 3..7 first; this one, whose seq mark was read before that
    write, accepts the vehicle's resend of 3..10 and writes it after."""
    async with replica(make_settings) as app:
        vid, vh, iid = await app.vehicle()
        assert await app.send(vh, iid, range(1, 3)) == 2
        await app.other_replica_writes(vid, range(3, 8))
        assert await app.send(vh, iid, range(3, 11)) == 8  # the copies made here
        every = list(range(1, 11))
        expected = {n: THEIRS if 3 <= n <= 7 else OURS for n in every}

        for limit in (100, 4, 1):
            samples = await app.paged(vid, limit)
            assert [s["seq"] for s in samples] == every, limit
            assert batteries(samples) == expected, limit
        track = (await app.view(vid, "track", **WINDOW)).json()
        assert [p["seq"] for p in track["points"]] == every
        assert batteries(track["points"]) == expected
        assert await app.csv_seqs(vid) == every
