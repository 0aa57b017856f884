"""follow_path with plan: true, through HTTP: the server routes round the other vehicles."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable

import pytest

from fleet_protocol import path_hash, route_of
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


@pytest.mark.parametrize("plan", [False, True])
async def test_a_path_or_path_hash_sent_by_the_client_is_refused(w: World, plan: bool) -> None:
    """``path`` and ``path_hash`` are the server's: a submit carrying either is 422 naming
    it, for one vehicle and for many, and nothing is queued (the vehicle would drive the
    client's path, which no check saw)."""
    a, b = await w.vehicle(), await w.vehicle()
    op = await w.person("operator", a, b)
    for v in (a, b):
        assert (await w.grant(v, op.username)).status_code == 200
    own = {"waypoints": [at(100, 0)], "plan": plan}
    sent = {"path": [{"lat": 0, "lon": 0}], "path_hash": "sha256:00"}
    for targets in ([a], [a, b]):
        for extra, fields in [
            ({"path": sent["path"]}, ["command.args.path"]),
            ({"path_hash": sent["path_hash"]}, ["command.args.path_hash"]),
            (sent, ["command.args.path", "command.args.path_hash"]),
            ({"path": None}, ["command.args.path"]),
        ]:
            command = {"type": "follow_path", "args": {**own, **extra}}
            r = await w.submit(op, targets, command)
            assert r.status_code == 422, (targets, extra, r.text)
            error = r.json()["error"]
            assert error["code"] == "invalid"
            assert [d["field"] for d in error["details"]] == fields
            assert all("filled in by the server" in d["message"] for d in error["details"])
    # Beside another bad arg, both are named.
    bad = {"type": "follow_path", "args": {"waypoints": [], "path": sent["path"]}}
    r = await w.submit(op, [a], bad)
    assert r.status_code == 422
    fields = [d["field"] for d in r.json()["error"]["details"]]
    assert fields == ["command.args.path", "command.args.waypoints"]
    for v in (a, b):
        assert await w.poll(v) == []
    # Without them, the route driven and hashed is the server's own.
    cid = await w.queued(op, a, {"type": "follow_path", "args": own})
    args = (await w.command(cid))["args"]
    assert ("path" in args) is plan
    assert args["path_hash"] == path_hash(route_of(args))
    assert route_of(args)[-1] == pytest.approx(at(100, 0))
