"""follow_path with plan: true, through HTTP: the server routes round the other vehicles."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable

import pytest

from server.domain.geo import from_local, to_local
from server.settings import Settings
from tests.server.commanding import World, world

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")

ORIGIN = (43.9, 15.4)


def at(x: float, y: float) -> dict[str, float]:
    lat, lon = from_local(x, y, *ORIGIN)
    return {"lat": lat, "lon": lon}


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    async with world(make_settings(safety_radius_m=5)) as w:
        yield w


async def test_a_planned_path_goes_round_another_vehicle(w: World) -> None:
    me, other = await w.vehicle(), await w.vehicle()
    await w.move_to(me, 1, *ORIGIN)
    middle = at(50, 0)
    await w.move_to(other, 1, middle["lat"], middle["lon"])
    op = await w.operator_in_control(me)
    goal = at(100, 0)
    command = {"type": "follow_path", "args": {"waypoints": [goal], "plan": True}}
    cid = await w.queued(op, me, command)
    path = (await w.command(cid))["args"]["path"]
    assert len(path) > 1
    assert path[-1] == pytest.approx(goal)
    # Every planned corner stays out of the other vehicle's safety radius.
    for point in path:
        x, y = to_local(point["lat"], point["lon"], *ORIGIN)
        assert (x - 50) ** 2 + y**2 >= 4.9**2


async def test_without_plan_the_path_is_left_to_the_vehicle(w: World) -> None:
    me = await w.vehicle()
    op = await w.operator_in_control(me)
    command = {"type": "follow_path", "args": {"waypoints": [at(100, 0)]}}
    cid = await w.queued(op, me, command)
    assert "path" not in (await w.command(cid))["args"]


async def test_a_waypoint_on_top_of_another_vehicle_is_422(w: World) -> None:
    me, other = await w.vehicle(), await w.vehicle()
    spot = at(100, 0)
    await w.move_to(other, 1, spot["lat"], spot["lon"])
    op = await w.operator_in_control(me)
    command = {"type": "follow_path", "args": {"waypoints": [spot], "plan": True}}
    r = await w.submit(op, [me], command)
    assert r.status_code == 422
    error = r.json()["error"]
    assert error["code"] == "invalid"
    assert other.vehicle_id in error["message"]
