"""Zones, pure: what a command may not do, where a vehicle is in breach, and the planner
kept out of no-go zones, in its operating area and apart from other paths."""

from __future__ import annotations

import pytest
import shapely
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from server.domain.access import Principal, zone_vehicles_seen
from server.domain.geo import from_local, to_local
from server.domain.plan_frame import corridor
from server.domain.planning import NoPath, plan_path
from server.domain.watch import (
    RulesSeen,
    WatchState,
    battery_event,
    battery_low,
    behind,
    change,
    cleared_data,
    next_state,
)
from server.domain.zones import (
    Area,
    ZoneSet,
    breaches,
    closest_routes,
    command_violation,
    keep_out,
    route_violation,
)

ORIGIN = (43.9, 15.4)


def at(x: float, y: float) -> tuple[float, float]:
    return from_local(x, y, *ORIGIN)


def area(
    zone_id: str,
    corners: list[tuple[float, float]],
    kind: str = "no_go",
    vehicles: frozenset[str] = frozenset(),
    clearance_m: float = 0.0,
) -> Area:
    ring = tuple(at(x, y) for x, y in [*corners, corners[0]])
    return Area(zone_id, zone_id, kind, (ring,), vehicles, clearance_m)  # type: ignore[arg-type]


def local_line(points: list[tuple[float, float]]) -> shapely.LineString:
    return shapely.LineString([to_local(*p, *ORIGIN) for p in points])


PIER = [(40.0, -30.0), (60.0, -30.0), (60.0, 30.0), (40.0, 30.0)]
BAY = [(-100.0, -100.0), (100.0, -100.0), (100.0, 100.0), (-100.0, 100.0)]
ZONES = ZoneSet((area("pier", PIER), area("bay", BAY, "operating_area", frozenset({"v1"}))), 3)


def test_a_target_in_a_no_go_zone_is_named() -> None:
    found = route_violation(ZONES, "v1", ORIGIN, [at(50, 0)])
    assert found is not None and found.zone_id == "pier" and found.kind == "no_go"
    assert "target is in no-go zone pier" in found.message


def test_a_straight_way_through_a_zone_is_refused_round_it_is_not() -> None:
    crossing = route_violation(ZONES, "v1", ORIGIN, [at(90, 0)])
    assert crossing is not None and "route crosses" in crossing.message
    assert route_violation(ZONES, "v1", ORIGIN, [at(0, 50), at(90, 50), at(90, 0)]) is None


def test_the_operating_area_holds_only_its_vehicles() -> None:
    out = route_violation(ZONES, "v1", ORIGIN, [at(0, 150)])
    assert out is not None and out.kind == "operating_area" and "outside" in out.message
    assert route_violation(ZONES, "v2", ORIGIN, [at(-150, 0)]) is None
    leaves = route_violation(ZONES, "v1", ORIGIN, [at(-90, 150), at(-90, 90)])
    assert leaves is not None and leaves.kind == "operating_area"


def test_a_vehicle_in_breach_may_leave() -> None:
    inside = at(50, 0)
    assert route_violation(ZONES, "v1", inside, [ORIGIN]) is None
    outside = at(0, 150)
    assert route_violation(ZONES, "v1", outside, [ORIGIN]) is None
    assert route_violation(ZONES, "v1", outside, [at(0, 160)]) is not None


#: A no-go zone shaped like a C open to the east: arms y 100..300 and -300..-100, its
#: back x -300..-100; the gap between the arms is open water.
C_ZONE = [
    (-300.0, -300.0),
    (300.0, -300.0),
    (300.0, -100.0),
    (-100.0, -100.0),
    (-100.0, 100.0),
    (300.0, 100.0),
    (300.0, 300.0),
    (-300.0, 300.0),
]


def test_a_vehicle_leaving_a_zone_may_not_come_back_into_it_on_the_way() -> None:
    """The leg a vehicle in a zone starts on is let off only until it is out: the
    straight way from the upper arm down through the lower one was let through whole."""
    zones = ZoneSet((area("harbour", C_ZONE),), 1)
    upper = at(0, 200)
    through = route_violation(zones, "v1", upper, [at(0, -400)])
    assert through is not None and through.message == "the route crosses no-go zone harbour"
    assert route_violation(zones, "v1", upper, [at(0, 0)]) is None  # out into the gap
    back = route_violation(zones, "v1", upper, [at(0, 0), at(0, 200)])
    assert back is not None and "point 1 of the route is in" in back.message
    # Out, then round the lower arm's end.
    assert route_violation(zones, "v1", upper, [at(0, 0), at(350, 0), at(350, -400)]) is None


def test_a_vehicle_coming_into_its_area_may_not_leave_it_again_on_the_way() -> None:
    # A U open to the north, the vehicle west of it: the straight way to the right arm
    # comes in through the left arm, leaves it over the gap and comes in again.
    u = [(-300.0, -300.0), (300.0, -300.0), (300.0, 300.0), (100.0, 300.0), (100.0, -100.0)]
    u += [(-100.0, -100.0), (-100.0, 300.0), (-300.0, 300.0)]
    zones = ZoneSet((area("bay", u, "operating_area", frozenset({"v1"})),), 1)
    west = at(-400, 0)
    across = route_violation(zones, "v1", west, [at(200, 0)])
    assert across is not None and "route leaves" in across.message
    assert route_violation(zones, "v1", west, [at(-200, 0)]) is None  # in, and stays
    round_ = route_violation(zones, "v1", west, [at(-200, 0), at(-200, -200), at(200, -200)])
    assert round_ is None  # in, then round the bottom of the U, inside it
    path = plan_path(west, [at(200, 0)], [], keep_out(zones, "v1"))
    assert route_violation(zones, "v1", west, path) is None
    route = local_line([west, *path])
    came_in = shapely.ops.substring(route, route.project(shapely.Point(-300, 0)), route.length)
    assert shapely.Polygon(u).buffer(0.01).covers(came_in)


def test_a_plan_from_inside_a_zone_leaves_it_and_goes_round_it() -> None:
    zones = ZoneSet((area("harbour", C_ZONE, clearance_m=5),), 1)
    upper, goal = at(0, 200), at(0, -400)
    path = plan_path(upper, [goal], [], keep_out(zones, "v1"))
    assert path[-1] == goal
    route = local_line([upper, *path])
    left = route.interpolate(route.project(shapely.Point(0, 95)))  # out of the upper arm
    after = shapely.ops.substring(route, route.project(left) + 0.1, route.length)
    assert not after.intersects(shapely.Polygon(C_ZONE).buffer(4.9))
    assert route_violation(zones, "v1", upper, path) is None


def test_commands_that_send_a_vehicle_nowhere_pass() -> None:
    assert command_violation(ZONES, "v1", "stop", {}, at(50, 0)) is None
    assert command_violation(ZONES, "v1", "keep_station", {}, at(150, 0)) is None
    kept = command_violation(
        ZONES, "v1", "keep_station", {"lat": at(50, 0)[0], "lon": at(50, 0)[1]}, None
    )
    assert kept is not None and kept.zone_id == "pier"
    path = {"waypoints": [dict(zip(("lat", "lon"), at(0, 50), strict=True))]}
    assert command_violation(ZONES, "v1", "follow_path", path, ORIGIN) is None


def test_breaches_name_the_zone_and_the_area() -> None:
    assert breaches(ZONES, "v1", ORIGIN) == frozenset()
    assert breaches(ZONES, "v1", at(50, 0)) == {"pier"}
    assert breaches(ZONES, "v1", at(150, 0)) == {"area:v1"}
    assert breaches(ZONES, "v2", at(150, 0)) == frozenset()


def test_the_watch_reports_entering_leaving_and_a_low_battery_once() -> None:
    start = WatchState()
    inside = next_state(start, ZONES, "v1", at(50, 0), 50.0, 20.0)
    moved = change(start, inside)
    assert moved.entered == {"pier"} and not moved.left and moved.battery is None
    low = next_state(inside, ZONES, "v1", ORIGIN, 19.0, 20.0)
    moved = change(inside, low)
    assert moved.left == {"pier"} and moved.battery == "low"
    wavering = next_state(low, ZONES, "v1", ORIGIN, 20.5, 20.0)
    assert not change(low, wavering)  # within the hysteresis: still low, no event
    back = next_state(wavering, ZONES, "v1", ORIGIN, 23.0, 20.0)
    assert change(wavering, back).battery == "recovered"
    assert battery_low(False, None, 20.0) is False


def test_a_zone_cleared_because_it_no_longer_applies_is_named_by_the_set_that_had_it() -> None:
    no_bay = ZoneSet((area("pier", PIER),), 4)
    no_zones = ZoneSet((), 5)
    gone = cleared_data([no_bay, ZONES], "v1", "area:v1")
    assert gone["zone"] == "bay" and gone["zone_id"] == "bay"
    assert gone["message"] == "its operating area bay no longer applies"
    assert cleared_data([no_zones, no_bay, ZONES], "v1", "pier")["message"] == (
        "no-go zone pier no longer applies"
    )
    left = cleared_data([ZONES], "v1", "pier")  # still there: the vehicle left it
    assert left["message"] == "left no-go zone pier"
    assert cleared_data([no_zones], "v1", "area:v1")["message"] == (
        "its operating area no longer applies"  # named by no set: said plainly
    )


def test_a_low_battery_ended_by_its_threshold_is_no_recovery() -> None:
    assert battery_event("low", 10.0, 20.0, rule=False) == "low_battery"
    assert battery_event("recovered", 23.0, 20.0, rule=False) == "battery_recovered"
    assert battery_event("recovered", 10.0, None, rule=False) == "low_battery_cleared"
    assert battery_event("recovered", 23.0, 20.0, rule=True) == "low_battery_cleared"


def test_closest_routes_finds_two_paths_too_close() -> None:
    a = [at(0, 0), at(100, 0)]
    b = [at(0, 5), at(100, 5)]
    c = [at(0, 50), at(100, 50)]
    found = closest_routes({"a": a, "b": b, "c": c}, 10)
    assert found is not None and found[:2] == ("a", "b") and found[2] == pytest.approx(5, abs=0.2)
    assert closest_routes({"a": a, "c": c}, 10) is None


def test_a_planned_path_stays_inside_the_operating_area() -> None:
    # A channel, and a pier across most of it: the way round stays in the channel.
    channel = [(-20.0, -40.0), (120.0, -40.0), (120.0, 40.0), (-20.0, 40.0)]
    zones = ZoneSet(
        (
            area("pier", [(40.0, -60.0), (60.0, -60.0), (60.0, 25.0), (40.0, 25.0)]),
            area("channel", channel, "operating_area", frozenset({"v1"})),
        ),
        2,
    )
    path = plan_path(ORIGIN, [at(100, 0)], [], keep_out(zones, "v1"))
    assert route_violation(zones, "v1", ORIGIN, path) is None
    assert shapely.Polygon(channel).covers(local_line([ORIGIN, *path]))


def rectangles() -> st.SearchStrategy[list[tuple[float, float, float, float]]]:
    corner = st.tuples(
        st.floats(-150, 150), st.floats(-150, 150), st.floats(10, 70), st.floats(10, 70)
    )
    return st.lists(corner, min_size=1, max_size=4)


POINT = st.tuples(st.floats(-220, 220), st.floats(-220, 220))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rects=rectangles(), start=POINT, goal=POINT, clearance=st.sampled_from([0.0, 3.0]))
def test_no_planned_path_crosses_a_no_go_zone(
    rects: list[tuple[float, float, float, float]],
    start: tuple[float, float],
    goal: tuple[float, float],
    clearance: float,
) -> None:
    boxes = [[(x, y), (x + w, y), (x + w, y + h), (x, y + h)] for x, y, w, h in rects]
    zones = ZoneSet(tuple(area(f"z{k}", b, clearance_m=clearance) for k, b in enumerate(boxes)), 1)
    assume(
        not any(shapely.Polygon(b).buffer(clearance).contains(shapely.Point(start)) for b in boxes)
    )
    try:
        path = plan_path(at(*start), [at(*goal)], [], keep_out(zones, "v"))
    except NoPath as exc:
        assert str(exc)  # refused with a reason
        # The planner's keep-out is the clearance a little grown (its arcs are chords).
        goal_blocked = any(
            shapely.Polygon(b).buffer(clearance * 1.03 + 0.01).intersects(shapely.Point(goal))
            for b in boxes
        )
        if not goal_blocked:
            # Refused with the goal clear: it must be enclosed by the zones' clearances.
            grown = shapely.union_all(
                [shapely.Polygon(b).buffer(clearance * 1.03 + 0.01) for b in boxes]
            )
            holes = [
                shapely.Polygon(r) for g in getattr(grown, "geoms", [grown]) for r in g.interiors
            ]
            assert any(
                h.contains(shapely.Point(goal)) or h.contains(shapely.Point(start)) for h in holes
            )
        return
    route = local_line([at(*start), *path])
    for b in boxes:
        assert not route.intersects(shapely.Polygon(b).buffer(clearance * 0.98 - 0.01))
    assert route_violation(zones, "v", at(*start), path) is None


FRACTION = st.floats(0.01, 0.99)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    rects=rectangles(),
    fx=FRACTION,
    fy=FRACTION,
    goal=POINT,
    clearance=st.sampled_from([0.0, 3.0]),
)
def test_a_plan_from_inside_zones_passes_their_check(
    rects: list[tuple[float, float, float, float]],
    fx: float,
    fy: float,
    goal: tuple[float, float],
    clearance: float,
) -> None:
    """A vehicle in a zone (or more): the path planned out of it is one the zones let it
    take (let off only until it is out), or the planner says why there is none."""
    boxes = [[(x, y), (x + w, y), (x + w, y + h), (x, y + h)] for x, y, w, h in rects]
    zones = ZoneSet(tuple(area(f"z{k}", b, clearance_m=clearance) for k, b in enumerate(boxes)), 1)
    x, y, w, h = rects[0]
    start = at(x + fx * w, y + fy * h)
    try:
        path = plan_path(start, [at(*goal)], [], keep_out(zones, "v"))
    except NoPath as exc:
        assert str(exc)
        return
    assert route_violation(zones, "v", start, path) is None


SEPARATION = 10.0


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(a0=POINT, a1=POINT, b0=POINT, b1=POINT)
def test_a_second_plan_keeps_the_separation_from_the_first_or_is_refused(
    a0: tuple[float, float],
    a1: tuple[float, float],
    b0: tuple[float, float],
    b1: tuple[float, float],
) -> None:
    first = plan_path(at(*a0), [at(*a1)], [])
    way = [at(*a0), *first]
    assume(local_line(way).distance(shapely.Point(b0)) > SEPARATION * 1.5)
    try:
        second = plan_path(at(*b0), [at(*b1)], [], [corridor(way, SEPARATION, "the first path")])
    except NoPath as exc:
        assert "the first path" in str(exc) or "no way round" in str(exc)
        return
    distance = local_line(way).distance(local_line([at(*b0), *second]))
    assert distance >= SEPARATION * 0.99


def test_a_judgement_by_older_rules_is_behind_one_by_newer() -> None:
    """Either version older is behind (a state judged by it may not replace the stored
    one); the same or newer in both is not."""
    stored = RulesSeen(zones=4, policy=2)
    assert behind(RulesSeen(3, 2), stored) and behind(RulesSeen(4, 1), stored)
    assert behind(RulesSeen(9, 1), stored)  # newer zones, older policy: still behind
    assert not behind(RulesSeen(4, 2), stored) and not behind(RulesSeen(5, 3), stored)
    assert not behind(RulesSeen(), RulesSeen())  # a state stored before they were kept


def test_who_sees_a_zone_and_which_of_its_vehicles() -> None:
    """A zone that lists vehicles is seen by those who see one of them, with only those;
    one that lists none concerns every vehicle and is everyone's; an admin sees it all."""
    ana = Principal("user", "ana", "operator", frozenset({"usv-1", "usv-2"}))
    ben = Principal("user", "ben", "operator", frozenset({"usv-3"}))
    admin = Principal("user", "root", "admin")
    listed = ["usv-2", "usv-3", "usv-9"]
    assert zone_vehicles_seen(listed, ana) == ["usv-2"]
    assert zone_vehicles_seen(listed, ben) == ["usv-3"]
    assert zone_vehicles_seen(listed, admin) == listed
    assert zone_vehicles_seen(["usv-9"], ana) is None
    assert zone_vehicles_seen([], ana) == [] and zone_vehicles_seen([], ben) == []
    vehicle = Principal("vehicle", "usv-3", vehicles=frozenset({"usv-3"}))
    assert zone_vehicles_seen(listed, vehicle) == ["usv-3"]
