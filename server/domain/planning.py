"""Path planning for ``follow_path`` with ``plan: true``. Pure.

Two kinds of obstacle, both in a local metric frame round the start:

- another vehicle: a disc (its position, the safety radius);
- a fixed obstacle (land, a pier, a no-go zone): a polygon grown by its clearance.

A leg whose straight line keeps every clearance is kept as is; otherwise the
shortest way round is found on a visibility graph: nodes on polygons
circumscribing the discs and on the outward corners of each grown polygon
(grown a little more, so the edges between corners stay clear), edges the
segments that keep every clearance, shortest path by Dijkstra.

A vehicle that starts inside obstacles (in a no-go zone, outside its operating
area, within another vehicle's radius) is first taken out of them, then routed
round everything, those it left too.

Fixed obstacles join a leg's graph lazily: first those the straight leg
crosses, then any the route found crosses, until a route crosses none. A
harbour full of piers thus costs only the piers near the way.

Bounded: a graph of at most :data:`MAX_ROUTE_NODES` nodes (its distances held
in one square array, searched by Dijkstra in it), and a :class:`Deadline` the
planner looks at between steps (each leg, each obstacle, each block of
:data:`SEGMENTS_PER_STEP` segments checked): past it, :class:`OutOfTime`. A
thread cannot be stopped from outside; this one stops itself.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import shapely

from server.domain.geo import from_local, to_local
from server.domain.plan_frame import (
    MARGIN,
    SIDES,
    TOUCH_M,
    XY,
    LatLon,
    LocalArea,
    Obstacle,
    Zone,
    clear,
    outside,
)

#: How far (m) past the edge of the obstacles it starts in a leaving vehicle is routed from.
EXIT_PAST_M = 0.05
#: Nodes of one leg's graph at most (their distances: a square array of this side).
MAX_ROUTE_NODES = 2000
#: Segments checked against the obstacles at once, between two looks at the deadline.
SEGMENTS_PER_STEP = 16_384


class NoPath(ValueError):
    """No path keeps the clearance (a waypoint is too close to an obstacle, or enclosed).
    ``waypoint``: the index (from 0, as a field path counts) of the waypoint refused, when
    one is; its message counts from 1, as the console numbers them."""

    def __init__(self, message: str, waypoint: int | None = None) -> None:
        super().__init__(message)
        self.waypoint = waypoint


class OutOfTime(Exception):
    """The planning went past its deadline."""


@dataclass(frozen=True)
class Deadline:
    """When the planner gives up: ``at`` on the scale of ``clock`` (seconds)."""

    at: float
    clock: Callable[[], float]

    def check(self) -> None:
        if self.clock() >= self.at:
            raise OutOfTime


#: No deadline: plan however long it takes.
NO_DEADLINE = Deadline(math.inf, lambda: 0.0)


def plan_path(
    start: LatLon | None,
    waypoints: Sequence[LatLon],
    obstacles: Sequence[Obstacle],
    zones: Sequence[Zone] = (),
    deadline: Deadline = NO_DEADLINE,
) -> list[LatLon]:
    """The path through ``waypoints`` in order, from ``start`` (or the first waypoint).

    The result begins with the first point after ``start`` and ends with the last waypoint.
    Raises :class:`NoPath` (no way keeps the clearances, or the way round has more than
    :data:`MAX_ROUTE_NODES` corners) or :class:`OutOfTime` (past ``deadline``).
    """
    if not waypoints:
        raise NoPath("no waypoints")
    origin = start if start is not None else waypoints[0]
    lat0, lon0 = origin
    centres = [to_local(o.lat, o.lon, lat0, lon0) for o in obstacles]
    radii = [o.radius_m for o in obstacles]
    areas = []
    for z in zones:
        deadline.check()
        areas.append(LocalArea(z, lat0, lon0))
    points = [to_local(lat, lon, lat0, lon0) for lat, lon in waypoints]
    _check_waypoints(np.array(points), centres, radii, obstacles, areas, deadline)
    here = to_local(*origin, lat0, lon0) if start is not None else points[0]
    out: list[XY] = [] if start is not None else [points[0]]
    for goal in points if start is not None else points[1:]:
        deadline.check()
        out.extend(_leg(here, goal, centres, radii, areas, deadline)[1:])
        here = goal
    exact = dict(zip(points, waypoints, strict=True))  # a waypoint as it was given
    return [exact.get((x, y)) or from_local(x, y, lat0, lon0) for x, y in out]


def _check_waypoints(
    xy: np.ndarray,
    centres: list[XY],
    radii: list[float],
    obstacles: Sequence[Obstacle],
    areas: list[LocalArea],
    deadline: Deadline,
) -> None:
    """:class:`NoPath` naming the first waypoint within a disc or an area (a disc first,
    then an area, each in the order given), counted from 1 as the console numbers them."""
    in_disc = np.zeros((len(xy), len(centres)), dtype=bool)
    if centres:
        c, r = np.array(centres), np.array(radii)
        in_disc = np.hypot(xy[:, None, 0] - c[None, :, 0], xy[:, None, 1] - c[None, :, 1]) < r
    in_area = np.zeros((len(xy), len(areas)), dtype=bool)
    for k, area in enumerate(areas):
        deadline.check()
        in_area[:, k] = shapely.intersects_xy(area.keep_out, xy[:, 0], xy[:, 1])
    bad = np.flatnonzero(in_disc.any(axis=1) | in_area.any(axis=1))
    if not len(bad):
        return
    index = int(bad[0])
    if in_disc[index].any():
        k = int(np.argmax(in_disc[index]))
        name = obstacles[k].name or "an obstacle"
        raise NoPath(f"waypoint {index + 1} is within {radii[k]:g} m of {name}", index)
    area = areas[int(np.argmax(in_area[index]))]
    within = f" or within its clearance of {area.clearance:g} m" if area.clearance else ""
    outside = "the outside of "  # the frame round an operating area (zones.keep_out)
    if area.label.startswith(outside):
        raise NoPath(f"waypoint {index + 1} is outside {area.label[len(outside) :]}{within}", index)
    raise NoPath(f"waypoint {index + 1} is inside {area.label}{within}", index)


def _leg(
    start: XY,
    goal: XY,
    centres: list[XY],
    radii: list[float],
    areas: list[LocalArea],
    deadline: Deadline,
) -> list[XY]:
    """The way from ``start`` to ``goal``, ``start`` first. A vehicle that starts inside
    obstacles is leaving them: it is taken out of them all first (:func:`_way_out`), and
    routed round everything from there, those too (so it does not come back in)."""
    out, straight = _way_out(start, goal, centres, radii, areas)
    head = [start] if out == start else [start, out]
    active: list[LocalArea] = []
    while True:
        route = _route(out, goal, centres, radii, active, deadline)
        line = shapely.LineString(route)
        crossed = [a for a in areas if a not in active and a.keep_out.intersects(line)]
        if not crossed:  # straight on from a way out on the straight way: one leg
            return [start, goal] if straight and len(route) == 2 else head + route[1:]
        active.extend(crossed)


def _way_out(
    start: XY, goal: XY, centres: list[XY], radii: list[float], areas: list[LocalArea]
) -> tuple[XY, bool]:
    """Where a vehicle at ``start`` is out of every disc and area it is in, a little past
    the last edge (``start`` itself when it is in none), and whether that is on the
    straight way to ``goal``. The route from there keeps clear of them all.

    Inside a zone itself (or outside its operating area) it heads straight for the goal
    (as the zones let it: only until it is out), or else takes the nearest way out; in a
    zone's clearance only, it takes the nearest way out (away from the zone: the
    straight way might cross it). Either way is taken only if it stays clear of every
    disc and area it does not start in; :class:`NoPath` when neither does."""
    in_discs = [
        i for i, (c, r) in enumerate(zip(centres, radii, strict=True)) if math.dist(start, c) < r
    ]
    in_areas = [a for a in areas if a.holds(*start)]
    if not in_discs and not in_areas:
        return start, True
    nearest = _nearest_out(start, [(centres[i], radii[i]) for i in in_discs], in_areas)
    in_zone = any(a.zone_holds(*start) for a in in_areas)
    ways = [_straight_out(start, goal, in_discs, centres, radii, in_areas), nearest]
    others = [i for i in range(len(centres)) if i not in in_discs]
    cs, rs = [centres[i] for i in others], [radii[i] for i in others]
    elsewhere = [a for a in areas if a not in in_areas]
    near = [a for a in in_areas if not a.zone_holds(*start)]  # in their clearance only
    for out in ways if in_zone or not in_areas else ways[1:]:
        if any(math.dist(out, centres[i]) < radii[i] for i in in_discs):
            continue
        if any(a.holds(*out) for a in in_areas):
            continue
        head = shapely.LineString([start, out])
        if any(a.zone_enters(head) for a in near):
            continue
        if clear(np.array([start]), np.array([out]), cs, rs, elsewhere)[0]:
            return out, out is ways[0] or _on_the_way(start, goal, out)
    names = ", ".join(a.label for a in in_areas) or "the vehicles round it"
    raise NoPath(f"no way out of {names} keeps clear of the other obstacles")


def _on_the_way(start: XY, goal: XY, point: XY) -> bool:
    """Whether ``point`` lies on the straight way from ``start`` to ``goal`` (to a mm)."""
    return math.dist(start, point) + math.dist(point, goal) - math.dist(start, goal) < TOUCH_M


def _straight_out(
    start: XY,
    goal: XY,
    in_discs: list[int],
    centres: list[XY],
    radii: list[float],
    in_areas: list[LocalArea],
) -> XY:
    """Along the straight way to the goal, a little past the last edge it crosses of the
    discs and areas ``start`` is in (each the first time the way leaves it)."""
    length = math.dist(start, goal)
    if length == 0:
        return start
    ux, uy = (goal[0] - start[0]) / length, (goal[1] - start[1]) / length
    along = 0.0
    for i in in_discs:  # the far root of |start + t u - c| = r
        dx, dy = start[0] - centres[i][0], start[1] - centres[i][1]
        b = dx * ux + dy * uy
        along = max(along, -b + math.sqrt(max(b * b - (dx * dx + dy * dy - radii[i] ** 2), 0.0)))
    line = shapely.LineString([start, goal])
    for area in in_areas:
        beyond = line.difference(area.keep_out)
        if not beyond.is_empty:
            coords = shapely.points(shapely.get_coordinates(beyond))
            along = max(along, float(shapely.line_locate_point(line, coords).min()))
    along = min(along + EXIT_PAST_M, length)
    return (start[0] + ux * along, start[1] + uy * along)


def _nearest_out(start: XY, discs: list[tuple[XY, float]], in_areas: list[LocalArea]) -> XY:
    """A little past the nearest point out of the discs and areas ``start`` is in."""
    parts = [a.keep_out for a in in_areas]
    parts += [shapely.Point(c).buffer(r * MARGIN, quad_segs=SIDES) for c, r in discs]
    edge = shapely.union_all(parts).boundary
    x, y = shapely.get_coordinates(shapely.shortest_line(shapely.Point(start), edge))[1]
    away = math.dist(start, (x, y)) or 1.0
    return (x + (x - start[0]) / away * EXIT_PAST_M, y + (y - start[1]) / away * EXIT_PAST_M)


def _route(
    start: XY, goal: XY, cs: list[XY], rs: list[float], areas: list[LocalArea], deadline: Deadline
) -> list[XY]:
    """Shortest way from ``start`` to ``goal`` round the discs and ``areas``."""
    if clear(np.array([start]), np.array([goal]), cs, rs, areas)[0]:
        return [start, goal]
    candidates: list[XY] = []
    for (cx, cy), r in zip(cs, rs, strict=True):
        ring = r * MARGIN / math.cos(math.pi / SIDES)
        for k in range(SIDES):
            angle = 2 * math.pi * k / SIDES
            candidates.append((cx + ring * math.cos(angle), cy + ring * math.sin(angle)))
    for area in areas:
        deadline.check()
        candidates.extend(area.corners)
    nodes = np.array([start, goal, *outside(candidates, cs, rs, areas)])
    if len(nodes) > MAX_ROUTE_NODES:
        raise NoPath(
            f"the way round has {len(nodes)} corners; at most {MAX_ROUTE_NODES} are planned "
            "round (fewer or simpler obstacles near the path)"
        )
    # Distances between the nodes a segment joins clear of everything, inf elsewhere.
    weights = np.full((len(nodes), len(nodes)), np.inf)
    first, second = np.triu_indices(len(nodes), k=1)
    for lo in range(0, len(first), SEGMENTS_PER_STEP):
        deadline.check()
        a, b = first[lo : lo + SEGMENTS_PER_STEP], second[lo : lo + SEGMENTS_PER_STEP]
        kept = clear(nodes[a], nodes[b], cs, rs, areas)
        a, b = a[kept], b[kept]
        weights[a, b] = weights[b, a] = np.hypot(*(nodes[a] - nodes[b]).T)
    route = _shortest(weights, deadline)
    if route is None:
        raise NoPath("no way round the obstacles keeps the clearance")
    return [(float(nodes[i][0]), float(nodes[i][1])) for i in route]


def _shortest(weights: np.ndarray, deadline: Deadline) -> list[int] | None:
    """Dijkstra from node 0 to node 1 over a square array of edge lengths (inf: no edge);
    the nodes of the shortest route, or None when 1 cannot be reached."""
    n = len(weights)
    dist = np.full(n, np.inf)
    dist[0] = 0.0
    before = np.full(n, -1)
    open_ = np.ones(n, dtype=bool)
    for step in range(n):
        if step % 256 == 0:
            deadline.check()
        u = int(np.argmin(np.where(open_, dist, np.inf)))
        if not open_[u] or dist[u] == np.inf:
            return None
        if u == 1:
            break
        open_[u] = False
        through = dist[u] + weights[u]
        better = open_ & (through < dist)
        dist[better] = through[better]
        before[better] = u
    route = [1]
    while route[-1] != 0:
        route.append(int(before[route[-1]]))
    return route[::-1]
