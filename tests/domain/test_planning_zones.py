"""Path planning round known fixed obstacles (polygons with a clearance), pure."""

from __future__ import annotations

import pytest
import shapely

from server.domain.geo import from_local, to_local
from server.domain.plan_frame import Obstacle, Zone
from server.domain.planning import NoPath, plan_path

ORIGIN = (43.9, 15.4)


def at(x: float, y: float) -> tuple[float, float]:
    return from_local(x, y, *ORIGIN)


def zone(corners: list[tuple[float, float]], clearance_m: float = 0.0, name: str = "") -> Zone:
    """A zone from its corners in the local frame (metres east, north of ORIGIN)."""
    ring = tuple(at(x, y) for x, y in [*corners, corners[0]])
    return Zone((ring,), clearance_m, name)


def shape(corners: list[tuple[float, float]]) -> shapely.Polygon:
    return shapely.Polygon(corners)


def line(
    path: list[tuple[float, float]], start: tuple[float, float] = ORIGIN
) -> shapely.LineString:
    return shapely.LineString([to_local(*p, *ORIGIN) for p in [start, *path]])


PIER = [(40.0, -30.0), (60.0, -30.0), (60.0, 30.0), (40.0, 30.0)]


def test_a_path_that_would_cross_a_polygon_goes_round_it_keeping_the_clearance() -> None:
    goal = at(100, 0)
    path = plan_path(ORIGIN, [goal], [], [zone(PIER, 5, "pier 3")])
    assert path[-1] == goal
    assert len(path) > 1
    route = line(path)
    assert not route.intersects(shape(PIER).buffer(5 * 0.99))
    assert route.length < 100 * 1.6  # round the end of the pier, not a tour


def test_without_a_clearance_the_path_may_pass_close_but_never_through() -> None:
    path = plan_path(ORIGIN, [at(100, 0)], [], [zone(PIER)])
    route = line(path)
    assert not route.crosses(shape(PIER))
    assert not route.intersects(shape(PIER).buffer(-0.01))


def test_a_goal_inside_a_bay_is_reached_through_its_mouth() -> None:
    # A U open to the west; the goal is inside it, the start south of it.
    bay = [(0, 50), (100, 50), (100, 150), (0, 150), (0, 140), (90, 140), (90, 60), (0, 60)]
    goal = at(50, 100)
    path = plan_path(ORIGIN, [goal], [], [zone(bay, 2)])
    assert path[-1] == goal
    assert not line(path).intersects(shape(bay).buffer(2 * 0.99))


def test_polygons_and_vehicles_are_avoided_together() -> None:
    other = at(30, -40)  # by the southern end of the pier, where the detour would go
    path = plan_path(ORIGIN, [at(100, 0)], [Obstacle(*other, 5, "usv-2")], [zone(PIER, 5)])
    route = line(path)
    assert not route.intersects(shape(PIER).buffer(5 * 0.99))
    assert route.distance(shapely.Point(to_local(*other, *ORIGIN))) >= 5 * 0.99


def test_a_polygon_met_only_on_the_way_round_another_is_avoided_too() -> None:
    # Off the straight line, but across the way round the pier's southern end.
    reef = [(45, -60), (80, -60), (80, -45), (45, -45)]
    path = plan_path(ORIGIN, [at(100, 0)], [], [zone(PIER, 5), zone(reef, 5)])
    route = line(path)
    assert not route.intersects(shape(PIER).buffer(4.95))
    assert not route.intersects(shape(reef).buffer(4.95))


def test_far_obstacles_leave_the_path_straight() -> None:
    goal = at(100, 0)
    far = [zone([(x, 500), (x + 50, 500), (x + 50, 550), (x, 550)], 20) for x in (-200, 0, 200)]
    assert plan_path(ORIGIN, [goal], [], far) == [goal]


def test_a_waypoint_inside_a_polygon_cannot_be_planned() -> None:
    with pytest.raises(NoPath, match="waypoint 2 is inside pier 3"):
        plan_path(ORIGIN, [at(0, 100), at(50, 0)], [], [zone(PIER, 5, "pier 3")])


def test_a_waypoint_within_the_clearance_cannot_be_planned() -> None:
    with pytest.raises(NoPath, match="waypoint 1"):
        plan_path(ORIGIN, [at(63, 0)], [], [zone(PIER, 5, "pier 3")])


def test_a_goal_enclosed_by_land_cannot_be_reached() -> None:
    lagoon_shore = Zone(
        (
            tuple(at(x, y) for x, y in [(0, 50), (100, 50), (100, 150), (0, 150), (0, 50)]),
            tuple(at(x, y) for x, y in [(20, 70), (20, 130), (80, 130), (80, 70), (20, 70)]),
        ),
        2,
        "island",
    )
    with pytest.raises(NoPath, match="no way round"):
        plan_path(ORIGIN, [at(50, 100)], [], [lagoon_shore])


def test_a_vehicle_starting_within_a_clearance_may_leave_it() -> None:
    start, goal = at(38, 0), at(0, 0)  # 2 m off the pier, inside its 5 m clearance
    assert plan_path(start, [goal], [], [zone(PIER, 5)]) == [goal]
