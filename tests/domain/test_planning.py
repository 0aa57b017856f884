"""Path planning round other vehicles, pure."""

from __future__ import annotations

import itertools
import math

import pytest

from server.domain.geo import from_local, to_local
from server.domain.plan_frame import SIDES, Obstacle
from server.domain.planning import MAX_ROUTE_NODES, Deadline, NoPath, OutOfTime, plan_path

ORIGIN = (43.9, 15.4)


def at(x: float, y: float) -> tuple[float, float]:
    return from_local(x, y, *ORIGIN)


def local(point: tuple[float, float]) -> tuple[float, float]:
    return to_local(*point, *ORIGIN)


def clearance(
    path: list[tuple[float, float]], start: tuple[float, float], centre: tuple[float, float]
) -> float:
    """Least distance (m) from ``centre`` to the polyline start -> path."""
    pts = [local(start), *(local(p) for p in path)]
    cx, cy = local(centre)
    least = math.inf
    for (ax, ay), (bx, by) in itertools.pairwise(pts):
        dx, dy = bx - ax, by - ay
        t = max(0.0, min(1.0, ((cx - ax) * dx + (cy - ay) * dy) / (dx * dx + dy * dy or 1)))
        least = min(least, math.hypot(ax + t * dx - cx, ay + t * dy - cy))
    return least


def length(path: list[tuple[float, float]], start: tuple[float, float]) -> float:
    pts = [local(start), *(local(p) for p in path)]
    return sum(math.dist(a, b) for a, b in itertools.pairwise(pts))


def test_a_clear_leg_stays_straight() -> None:
    goal = at(100, 0)
    path = plan_path(ORIGIN, [goal], [Obstacle(*at(50, 30), 5)])
    assert path == [goal]


def test_the_path_goes_round_a_vehicle_in_the_way_keeping_the_radius() -> None:
    goal, other = at(100, 0), at(50, 0)
    path = plan_path(ORIGIN, [goal], [Obstacle(*other, 5)])
    assert len(path) > 1
    assert path[-1] == goal
    assert clearance(path, ORIGIN, other) >= 5 * 0.99
    assert length(path, ORIGIN) < 100 * 1.05  # a detour, not a tour


def test_several_waypoints_are_visited_in_order() -> None:
    wps = [at(100, 0), at(100, 100)]
    blockers = [Obstacle(*at(50, 0), 5), Obstacle(*at(100, 50), 5)]
    path = plan_path(ORIGIN, wps, blockers)
    assert path[-1] == wps[1]
    assert wps[0] in path
    assert path.index(wps[0]) < len(path) - 1
    for o in blockers:
        assert clearance(path, ORIGIN, (o.lat, o.lon)) >= 5 * 0.99


def test_without_a_start_the_path_begins_at_the_first_waypoint() -> None:
    wps = [at(0, 0), at(100, 0)]
    path = plan_path(None, wps, [Obstacle(*at(50, 0), 5)])
    assert path[0] == wps[0]
    assert path[-1] == wps[1]
    assert len(path) > 2


def test_a_vehicle_starting_inside_a_radius_may_leave_it() -> None:
    goal = at(100, 0)
    assert plan_path(ORIGIN, [goal], [Obstacle(*at(2, 0), 5)]) == [goal]


def test_a_waypoint_within_the_radius_of_a_vehicle_cannot_be_planned() -> None:
    with pytest.raises(NoPath, match="waypoint 1"):
        plan_path(ORIGIN, [at(100, 0)], [Obstacle(*at(102, 0), 5, "usv-9")])


def test_an_enclosed_goal_cannot_be_reached() -> None:
    ring = [
        Obstacle(*at(100 + 9 * math.cos(a / 8 * math.tau), 9 * math.sin(a / 8 * math.tau)), 5)
        for a in range(8)
    ]
    with pytest.raises(NoPath):
        plan_path(ORIGIN, [at(100, 0)], ring)


def test_past_the_deadline_the_planner_stops() -> None:
    late = Deadline(at=1.0, clock=lambda: 2.0)
    with pytest.raises(OutOfTime):
        plan_path(ORIGIN, [at(100, 0)], [Obstacle(*at(50, 0), 5)], deadline=late)


def test_the_deadline_is_looked_at_while_a_leg_is_worked_out() -> None:
    looks = itertools.count()
    # The first look (before the only leg) is in time, the next (within the leg) is not.
    deadline = Deadline(at=1.0, clock=lambda: float(next(looks)))
    with pytest.raises(OutOfTime):
        plan_path(ORIGIN, [at(100, 0)], [Obstacle(*at(50, 0), 5)], deadline=deadline)


def test_a_way_round_with_too_many_corners_is_refused() -> None:
    discs = MAX_ROUTE_NODES // SIDES + 1  # each disc brings SIDES corners
    others = [Obstacle(*at(50, 0), 5)] + [
        Obstacle(*at(-1000 + 40 * (k % 50), 200 + 40 * (k // 50)), 5) for k in range(discs)
    ]
    with pytest.raises(NoPath, match=f"at most {MAX_ROUTE_NODES}"):
        plan_path(ORIGIN, [at(100, 0)], others)
