"""The watch judges what the vehicle reports now: the sample that becomes its latest
position. One dated far ahead (a GPS or clock glitch: 2099) is stored but is never the
position (docs/api.md), so it raises no alarm, records no breach and makes the server
send nothing; nor does one that came late."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from datetime import UTC, datetime, timedelta
from typing import Any

import httpx
import pytest

from server.app import create_app
from server.settings import Settings
from tests.factories import ADMIN, make_vehicle, sample
from tests.live import call, connect, serve
from tests.server.commanding import Vehicle, World, world
from tests.server.test_obstacles import at, polygon
from tests.server.test_zones import zone

pytestmark = pytest.mark.usefixtures("store_backend")

#: A square of 200 m round the origin of ``at``: the vehicle's operating area.
AREA = [(-100.0, -100.0), (100.0, -100.0), (100.0, 100.0), (-100.0, 100.0)]
GLITCH = datetime(2099, 6, 1, tzinfo=UTC)


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    async with world(make_settings()) as w:
        yield w


async def report(
    w: World, me: Vehicle, seq: int, ts: datetime, x: float = 0.0, **more: Any
) -> dict[str, Any]:
    lat, lon = at(x, 0).values()
    body = {
        "instance_id": me.instance_id,
        "samples": [sample(seq, ts=ts, lat=lat, lon=lon, **more)],
    }
    r = await w.http.post("/upper/update_param", headers=me.headers, json=body)
    assert r.status_code == 200, r.text
    await w.services.messages.drain()  # the watch has judged the batch
    answer: dict[str, Any] = r.json()
    return answer


async def view(w: World, me: Vehicle) -> dict[str, Any]:
    r = await w.http.get(f"/api/vehicles/{me.vehicle_id}", headers=ADMIN)
    assert r.status_code == 200, r.text
    got: dict[str, Any] = r.json()
    return got


async def event_kinds(w: World, me: Vehicle) -> list[str]:
    r = await w.http.get("/api/events", headers=ADMIN, params={"vehicle_id": me.vehicle_id})
    assert r.status_code == 200, r.text
    return [e["kind"] for e in r.json()["events"]]


async def failsafe(w: World, me: Vehicle, **policy: Any) -> None:
    r = await w.http.put(f"/api/vehicles/{me.vehicle_id}/failsafe", headers=ADMIN, json=policy)
    assert r.status_code == 200, r.text


async def test_a_sample_dated_far_ahead_breaches_no_zone_and_sends_no_failsafe(w: World) -> None:
    me = await w.vehicle()
    await zone(
        w,
        {
            "name": "area9",
            "kind": "operating_area",
            "polygon": polygon(AREA),
            "vehicles": [me.vehicle_id],
        },
    )
    await failsafe(w, me, action="stop", on_breach=True)
    await report(w, me, 1, w.clock())  # inside its area
    # Far out of the area, and years ahead: stored, never the position.
    assert (await report(w, me, 2, GLITCH, x=5_000.0))["accepted"] == 1
    seen = await view(w, me)
    assert seen["position"]["seq"] == 1
    assert seen["alarms"] == []
    assert "zone_breach" not in await event_kinds(w, me)
    assert await w.poll(me) == []  # no failsafe stop was queued

    # Five minutes ahead is a clock a little fast: that one is the position, and judged.
    await report(w, me, 3, w.clock() + timedelta(minutes=4), x=5_000.0)
    seen = await view(w, me)
    assert seen["position"]["seq"] == 3
    assert [a["kind"] for a in seen["alarms"]] == ["outside_area"]
    assert [c["type"] for c in await w.poll(me)] == ["stop"]


async def test_a_battery_reading_dated_far_ahead_raises_no_alarm(w: World) -> None:
    me = await w.vehicle()
    await failsafe(w, me, low_battery_pct=50.0)
    await report(w, me, 1, w.clock(), battery_pct=90.0)
    await report(w, me, 2, GLITCH, battery_pct=5.0)
    assert (await view(w, me))["alarms"] == []
    assert "low_battery" not in await event_kinds(w, me)

    await report(w, me, 3, w.clock() + timedelta(seconds=1), battery_pct=40.0)
    [low] = (await view(w, me))["alarms"]
    assert low["message"] == "battery low: 40 % (alarm below 50 %)"
    # back over the threshold, not past its margin: still low, and said why
    await report(w, me, 4, w.clock() + timedelta(seconds=2), battery_pct=51.0)
    [low] = (await view(w, me))["alarms"]
    assert low["message"] == "battery low: 51 % (alarm below 50 %, kept until 52 %)"
    await report(w, me, 5, w.clock() + timedelta(seconds=3), battery_pct=52.0)
    assert (await view(w, me))["alarms"] == []


async def test_a_late_sample_newer_than_the_position_but_stale_is_not_judged(w: World) -> None:
    """A sample older than ``offline_after_s`` when it arrives came from an outbox: it may
    be the newest the server has, but it is not the vehicle now."""
    me = await w.vehicle()
    await failsafe(w, me, low_battery_pct=50.0)
    await report(w, me, 1, w.clock() - timedelta(minutes=10), battery_pct=90.0)
    await report(w, me, 2, w.clock() - timedelta(minutes=9), battery_pct=5.0)
    seen = await view(w, me)
    assert seen["position"]["seq"] == 2
    assert seen["alarms"] == []


async def test_on_the_vehicle_s_socket_too(make_settings: Callable[..., Settings]) -> None:
    settings = make_settings()
    app = create_app(settings)
    async with serve(settings, app=app) as base, httpx.AsyncClient(base_url=base) as api:
        vid, vh = await make_vehicle(api)
        r = await api.put(
            f"/api/vehicles/{vid}/failsafe", headers=ADMIN, json={"low_battery_pct": 50}
        )
        assert r.status_code == 200, r.text
        token = vh["Authorization"].removeprefix("Bearer ")
        async with await connect(base, "/ws/vehicle", token) as ws:
            started = await call(ws, "start_instance", "s", vehicle_id=vid, capabilities=["stop"])
            iid = started["instance_id"]
            now = datetime.now(UTC)
            for seq, ts, pct in ((1, now, 90.0), (2, GLITCH, 5.0)):
                got = await call(
                    ws,
                    "update_param",
                    f"u{seq}",
                    instance_id=iid,
                    samples=[sample(seq, ts=ts, battery_pct=pct)],
                )
                assert got["ok"] is True and got["accepted"] == 1, got
        await app.state.services.messages.drain()
        seen = (await api.get(f"/api/vehicles/{vid}", headers=ADMIN)).json()
        assert seen["position"]["seq"] == 1 and seen["alarms"] == []
