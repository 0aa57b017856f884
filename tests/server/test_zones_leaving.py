"""A vehicle in a no-go zone sent out of it through HTTP: let off only until it is out,
and planned out and round (the zones' rules: docs/safety.md)."""

from __future__ import annotations

import pytest
import shapely
from shapely.geometry import shape

from tests.server.commanding import World
from tests.server.test_obstacles import at
from tests.server.test_zones import go_to, no_go, w, zone

pytestmark = pytest.mark.usefixtures("store_backend")
__all__ = ["w"]  # the fixture, taken from test_zones


#: A no-go zone shaped like a C open to the east: arms y 100..300 and -300..-100.
HARBOUR = [(-300, -300), (300, -300), (300, -100), (-100, -100), (-100, 100), (300, 100)]
HARBOUR += [(300, 300), (-300, 300)]


async def test_a_vehicle_leaving_a_zone_is_not_sent_back_into_it(w: World) -> None:
    """In the C's upper arm, a go_to below the C was let through the lower arm (the leg
    a vehicle in a zone starts on was let off whole); planned, the path now leaves the
    upper arm and goes round the lower one."""
    harbour = shape((await zone(w, no_go("harbour", HARBOUR, clearance_m=5)))["polygon"])
    me = await w.vehicle()
    await w.move_to(me, 1, *at(0, 200).values())
    op = await w.operator_in_control(me)
    r = await w.submit(op, [me], go_to(0, -400))
    assert r.status_code == 422 and r.json()["error"]["code"] == "zone_violation", r.text
    assert r.json()["error"]["message"] == "the route crosses no-go zone harbour"
    assert (await w.submit(op, [me], go_to(0, 0))).status_code == 202  # out, into the gap
    planned = {"type": "follow_path", "args": {"waypoints": [at(0, -400)], "plan": True}}
    path = (await w.command(await w.queued(op, me, planned)))["args"]["path"]
    assert path[-1] == pytest.approx(at(0, -400))
    out, *rest = [(p["lon"], p["lat"]) for p in path]
    assert not harbour.covers(shapely.Point(out))  # the way out of the upper arm
    assert not shapely.LineString([out, *rest]).intersects(harbour.buffer(-1e-7))
