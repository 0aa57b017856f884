"""A vehicle's alarms follow the rules they are judged by: when a zone is drawn, changed
or deleted, or a failsafe policy's battery threshold is set or lifted, each vehicle it
touches is judged again at once against its latest position (one that stopped
reporting too), and the event says why an alarm began or ended."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from datetime import datetime
from typing import Any

import pytest

from server.settings import Settings
from tests.factories import ADMIN
from tests.server.commanding import Vehicle, World, eventually, world
from tests.server.test_obstacles import PIER, polygon
from tests.server.test_watch_now import AREA, failsafe, report, view
from tests.server.test_zones import no_go, zone

pytestmark = pytest.mark.usefixtures("store_backend")


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    async with world(make_settings()) as w:
        yield w


async def events(w: World, me: Vehicle, kind: str) -> list[dict[str, Any]]:
    r = await w.http.get(
        "/api/events", headers=ADMIN, params={"vehicle_id": me.vehicle_id, "kind": kind}
    )
    assert r.status_code == 200, r.text
    found: list[dict[str, Any]] = r.json()["events"]
    return found


async def alarm_kinds(w: World, me: Vehicle) -> list[str]:
    return [a["kind"] for a in (await view(w, me))["alarms"]]


async def until_alarms(w: World, me: Vehicle, want: list[str]) -> None:
    async def holds() -> bool:
        return await alarm_kinds(w, me) == want

    await eventually(holds)


async def until_events(w: World, me: Vehicle, kind: str, count: int) -> list[dict[str, Any]]:
    """The vehicle's events of ``kind`` once there are ``count`` (an alarm's event is
    recorded just after the alarm itself, which the view shows first)."""
    found: list[dict[str, Any]] = []

    async def holds() -> bool:
        found[:] = await events(w, me, kind)
        return len(found) >= count

    await eventually(holds)
    return found


def area(me: Vehicle, name: str = "area9") -> dict[str, Any]:
    return {
        "name": name,
        "kind": "operating_area",
        "polygon": polygon(AREA),
        "vehicles": [me.vehicle_id],
    }


async def test_deleting_the_area_a_vehicle_is_outside_of_ends_its_alarm_at_once(
    w: World,
) -> None:
    me = await w.vehicle()
    made = await zone(w, area(me))
    await report(w, me, 1, w.clock(), x=500.0)  # outside its only area
    assert await alarm_kinds(w, me) == ["outside_area"]

    gone = await w.http.delete(f"/api/zones/{made['zone_id']}", headers=ADMIN)
    assert gone.status_code == 200, gone.text
    assert await alarm_kinds(w, me) == []  # judged again before the answer
    [cleared] = await events(w, me, "zone_cleared")
    assert cleared["data"]["zone_id"] == made["zone_id"]
    assert cleared["data"]["zone"] == "area9"
    assert cleared["data"]["zone_kind"] == "operating_area"
    assert cleared["data"]["message"] == "its operating area area9 no longer applies"
    assert cleared["data"]["reason"] == "zones_changed"

    w.clock.advance(1)
    await report(w, me, 2, w.clock(), x=510.0)  # the next sample has nothing to clear
    assert len(await events(w, me, "zone_cleared")) == 1
    assert await alarm_kinds(w, me) == []


async def test_a_no_go_zone_drawn_over_a_silent_vehicle_is_a_breach_at_once(w: World) -> None:
    me = await w.vehicle()
    await failsafe(w, me, action="stop", on_breach=True)
    await report(w, me, 1, w.clock(), x=50.0)  # where the pier will be; then it says nothing
    w.clock.advance(60)  # offline by now: still held against the new zone

    pier = await zone(w, no_go())
    [alarm] = (await view(w, me))["alarms"]
    assert alarm["kind"] == "no_go_zone" and alarm["zone_id"] == pier["zone_id"]
    [breach] = await events(w, me, "zone_breach")
    assert breach["data"]["reason"] == "zones_changed"
    assert breach["data"]["command_type"] == "stop"

    moved = await w.http.patch(
        f"/api/zones/{pier['zone_id']}",
        headers=ADMIN,
        json={"polygon": polygon([(x + 100.0, y) for x, y in PIER])},
    )
    assert moved.status_code == 200, moved.text
    assert await alarm_kinds(w, me) == []
    [cleared] = await events(w, me, "zone_cleared")
    assert cleared["data"]["message"] == "left no-go zone pier 3"
    assert cleared["data"]["reason"] == "zones_changed"


async def test_lifting_the_battery_threshold_ends_the_alarm_without_a_recovery(
    w: World,
) -> None:
    me = await w.vehicle()
    await failsafe(w, me, low_battery_pct=50.0)
    await report(w, me, 1, w.clock(), battery_pct=30.0)
    assert await alarm_kinds(w, me) == ["low_battery"]

    await failsafe(w, me)  # no threshold now
    await until_alarms(w, me, [])
    [ended] = await until_events(w, me, "low_battery_cleared", 1)
    assert ended["data"]["battery_pct"] == 30.0
    assert ended["data"]["threshold_pct"] is None
    assert ended["data"]["reason"] == "failsafe_changed"

    w.clock.advance(1)
    await report(w, me, 2, w.clock(), battery_pct=30.0)
    assert await events(w, me, "battery_recovered") == []

    await failsafe(w, me, low_battery_pct=40.0)  # a threshold above the reading: low again
    await until_alarms(w, me, ["low_battery"])
    lows = await until_events(w, me, "low_battery", 2)
    assert [e["data"].get("reason") for e in lows] == [None, "failsafe_changed"]
    assert lows[-1]["data"]["threshold_pct"] == 40.0
    [alarm] = (await view(w, me))["alarms"]
    assert alarm["message"] == "battery low: 30 % (alarm below 40 %)"
    assert datetime.fromisoformat(alarm["since"]) == w.clock()  # when the rule moved
