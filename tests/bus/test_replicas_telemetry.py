"""Telemetry across two replicas on one store, joined by a real redis-server.

A replica caches a vehicle's ``seq`` high-water mark; when the vehicle starts
or resumes its instance there, the replica reads the mark from the store again
(the vehicle may have sent samples through the other replica since).
"""

from __future__ import annotations

from collections.abc import Callable

import httpx
import pytest

from server.settings import Settings
from tests.bus.conftest import RedisServer
from tests.bus.test_replicas_shared_store import two_replicas
from tests.factories import ADMIN, make_vehicle, sample, start_instance

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


async def _send(api: httpx.AsyncClient, headers: dict[str, str], iid: str, seqs: range) -> int:
    r = await api.post(
        "/upper/update_param",
        headers=headers,
        json={"instance_id": iid, "samples": [sample(n) for n in seqs]},
    )
    assert r.status_code == 200, r.text
    accepted: int = r.json()["accepted"]
    return accepted


async def test_resuming_on_a_replica_reads_the_seq_mark_again(
    make_settings: Callable[..., Settings], redis_server: RedisServer
) -> None:
    # Five samples to a bucket: a batch of five is written before its call is answered.
    async with two_replicas(make_settings, redis_server, bucket_samples=5) as (api_a, api_b, _):
        vid, vh = await make_vehicle(api_a)
        iid = (await start_instance(api_b, vid, vh))["instance_id"]
        assert await _send(api_b, vh, iid, range(1, 6)) == 5  # B caches its mark: 5
        moved = await start_instance(api_a, vid, vh)
        assert (moved["instance_id"], moved["resumed"], moved["last_seq"]) == (iid, True, 5)
        assert await _send(api_a, vh, iid, range(6, 11)) == 5  # written by A
        back = await start_instance(api_b, vid, vh)
        assert (back["resumed"], back["last_seq"]) == (True, 10)
        # The agent resends from its outbox: B counts A's samples as duplicates.
        assert await _send(api_b, vh, iid, range(6, 13)) == 2
        r = await api_b.get(f"/api/vehicles/{vid}/telemetry", headers=ADMIN)
        assert [s["seq"] for s in r.json()["samples"]] == list(range(1, 13))
