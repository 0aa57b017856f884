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

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import shapely

from server.domain.geo import from_local, to_local

#: Vertices of the polygon put round each disc; more: shorter detours, slower planning.
SIDES = 12
#: Margin so that the polygon's edges stay outside the disc despite rounding.
MARGIN = 1.02
#: Fixed obstacles: the graph's corners lie this much (m) beyond the clearance, plus 2 %.
CORNER_GAP_M = 0.25
#: A segment may come this close (m) inside a clearance (rounding): touching is not crossing.
TOUCH_M = 1e-3
#: How far (m) past the edge of the obstacles it starts in a leaving vehicle is routed from.
EXIT_PAST_M = 0.05
#: A point less than this (m) inside a zone's edge is on it (the zones' check of a route
#: allows a rounding's width there, ``zones.EDGE_DEG``: about 2 mm).
EDGE_M = 3e-3
#: Segments per quarter circle where a polygon is grown round a corner.
ARC_SEGMENTS = 4
#: Nodes of one leg's graph at most (their distances: a square array of this side).
MAX_ROUTE_NODES = 2000
#: Segments checked against the obstacles at once, between two looks at the deadline.
SEGMENTS_PER_STEP = 16_384

LatLon = tuple[float, float]
XY = tuple[float, float]


class NoPath(ValueError):
    """No path keeps the clearance (a waypoint is too close to an obstacle, or enclosed)."""


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


@dataclass(frozen=True)
class Obstacle:
    """Another vehicle: a disc of ``radius_m`` round its position."""

    lat: float
    lon: float
    radius_m: float
    name: str = ""


@dataclass(frozen=True)
class Zone:
    """A fixed obstacle: a polygon, its rings as (lat, lon) (the first is the outside,
    any others holes), and the clearance a path keeps from it."""

    rings: tuple[tuple[LatLon, ...], ...]
    clearance_m: float = 0.0
    name: str = ""


class _Area:
    """A zone in the local frame: what a path may not enter, and the graph's corners."""

    def __init__(self, zone: Zone, lat0: float, lon0: float) -> None:
        shell, *holes = [[to_local(lat, lon, lat0, lon0) for lat, lon in r] for r in zone.rings]
        polygon = shapely.make_valid(shapely.Polygon(shell, holes))
        self.label = zone.name or "a fixed obstacle"
        self.clearance = zone.clearance_m
        # Few segments per arc, the arcs pushed out so that their chords keep the clearance.
        grow = zone.clearance_m / math.cos(math.pi / (4 * ARC_SEGMENTS)) if zone.clearance_m else 0
        self.keep_out = polygon.buffer(grow - TOUCH_M, quad_segs=ARC_SEGMENTS)
        shapely.prepare(self.keep_out)
        self._polygon, self._gap = polygon, zone.clearance_m * 1.02 + CORNER_GAP_M

    @functools.cached_property
    def corners(self) -> list[XY]:
        """The graph's corners, built when a route first meets this area (most never do)."""
        grown = shapely.orient_polygons(
            self._polygon.buffer(self._gap, join_style="mitre", mitre_limit=2.0),
            exterior_cw=False,
        )
        return _outward_corners(grown)

    def holds(self, x: float, y: float) -> bool:
        """Whether the point is in the area or its clearance."""
        return bool(shapely.intersects_xy(self.keep_out, x, y))

    def zone_holds(self, x: float, y: float) -> bool:
        """Whether the point is in the area itself (its clearance aside), further in than
        a rounding's width from the edge (the zones' check has such a point on it)."""
        return bool(shapely.intersects_xy(self._core, x, y))

    def zone_enters(self, line: shapely.Geometry) -> bool:
        """Whether ``line`` reaches into the area itself (as :meth:`zone_holds` has it)."""
        return bool(self._core.intersects(line))

    @functools.cached_property
    def _core(self) -> shapely.Geometry:
        return self._polygon.buffer(-EDGE_M)


def _outward_corners(polygon: shapely.Geometry) -> list[XY]:
    """The corners a shortest path may bend round: left turns of each ring (exterior
    counter-clockwise, holes clockwise: the obstacle is always on the left)."""
    out: list[XY] = []
    for part in shapely.get_parts(polygon):
        rings = [part.exterior, *part.interiors] if isinstance(part, shapely.Polygon) else []
        for ring in rings:
            pts = np.asarray(ring.coords)[:-1]
            if len(pts) < 3:
                continue
            before, after = pts - np.roll(pts, 1, axis=0), np.roll(pts, -1, axis=0) - pts
            turn = before[:, 0] * after[:, 1] - before[:, 1] * after[:, 0]
            out.extend((float(x), float(y)) for x, y in pts[turn > 0])
    return out


def corridor(route: Sequence[LatLon], width_m: float, name: str) -> Zone:
    """The band ``width_m`` either side of ``route`` (straight legs) as a fixed obstacle:
    a path planned round it keeps that separation from the route."""
    lat0, lon0 = route[0]
    local = [to_local(lat, lon, lat0, lon0) for lat, lon in route]
    line = shapely.LineString(local) if len(local) > 1 else shapely.Point(local[0])
    band = line.buffer(width_m / math.cos(math.pi / (4 * ARC_SEGMENTS)), quad_segs=ARC_SEGMENTS)
    rings = [band.exterior, *band.interiors]
    return Zone(
        tuple(tuple(from_local(x, y, lat0, lon0) for x, y in r.coords) for r in rings), 0.0, name
    )


def crossed(route: Sequence[LatLon], obstacles: Sequence[Zone]) -> list[str]:
    """The names of the obstacles the straight legs of ``route`` run into (their outline,
    clearance aside): what a vehicle sent that way, unplanned, would meet."""
    if not route or not obstacles:
        return []
    lat0, lon0 = route[0]  # a metric frame round the start: each leg the short way round
    positions = [to_local(lat, lon, lat0, lon0) for lat, lon in route]
    line = shapely.LineString(positions) if len(positions) > 1 else shapely.Point(positions[0])
    hit = []
    for zone in obstacles:
        shell, *holes = ([to_local(lat, lon, lat0, lon0) for lat, lon in r] for r in zone.rings)
        if shapely.make_valid(shapely.Polygon(shell, holes)).intersects(line):
            hit.append(zone.name or "a fixed obstacle")
    return hit


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
        areas.append(_Area(z, lat0, lon0))
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
    areas: list[_Area],
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
        raise NoPath(
            f"waypoint {index + 1} is within {radii[k]:g} m of {obstacles[k].name or 'an obstacle'}"
        )
    area = areas[int(np.argmax(in_area[index]))]
    within = f" or within its clearance of {area.clearance:g} m" if area.clearance else ""
    outside = "the outside of "  # the frame round an operating area (zones.keep_out)
    if area.label.startswith(outside):
        raise NoPath(f"waypoint {index + 1} is outside {area.label[len(outside) :]}{within}")
    raise NoPath(f"waypoint {index + 1} is inside {area.label}{within}")


def _leg(
    start: XY,
    goal: XY,
    centres: list[XY],
    radii: list[float],
    areas: list[_Area],
    deadline: Deadline,
) -> list[XY]:
    """The way from ``start`` to ``goal``, ``start`` first. A vehicle that starts inside
    obstacles is leaving them: it is taken out of them all first (:func:`_way_out`), and
    routed round everything from there, those too (so it does not come back in)."""
    out, straight = _way_out(start, goal, centres, radii, areas)
    head = [start] if out == start else [start, out]
    active: list[_Area] = []
    while True:
        route = _route(out, goal, centres, radii, active, deadline)
        line = shapely.LineString(route)
        crossed = [a for a in areas if a not in active and a.keep_out.intersects(line)]
        if not crossed:  # straight on from a way out on the straight way: one leg
            return [start, goal] if straight and len(route) == 2 else head + route[1:]
        active.extend(crossed)


def _way_out(
    start: XY, goal: XY, centres: list[XY], radii: list[float], areas: list[_Area]
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
        if _clear(np.array([start]), np.array([out]), cs, rs, elsewhere)[0]:
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
    in_areas: list[_Area],
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


def _nearest_out(start: XY, discs: list[tuple[XY, float]], in_areas: list[_Area]) -> XY:
    """A little past the nearest point out of the discs and areas ``start`` is in."""
    parts = [a.keep_out for a in in_areas]
    parts += [shapely.Point(c).buffer(r * MARGIN, quad_segs=SIDES) for c, r in discs]
    edge = shapely.union_all(parts).boundary
    x, y = shapely.get_coordinates(shapely.shortest_line(shapely.Point(start), edge))[1]
    away = math.dist(start, (x, y)) or 1.0
    return (x + (x - start[0]) / away * EXIT_PAST_M, y + (y - start[1]) / away * EXIT_PAST_M)


def _route(
    start: XY, goal: XY, cs: list[XY], rs: list[float], areas: list[_Area], deadline: Deadline
) -> list[XY]:
    """Shortest way from ``start`` to ``goal`` round the discs and ``areas``."""
    if _clear(np.array([start]), np.array([goal]), cs, rs, areas)[0]:
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
    nodes = np.array([start, goal, *_outside(candidates, cs, rs, areas)])
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
        clear = _clear(nodes[a], nodes[b], cs, rs, areas)
        a, b = a[clear], b[clear]
        weights[a, b] = weights[b, a] = np.hypot(*(nodes[a] - nodes[b]).T)
    route = _shortest(weights, deadline)
    if route is None:
        raise NoPath("no way round the obstacles keeps the clearance")
    return [(float(nodes[i][0]), float(nodes[i][1])) for i in route]


def _outside(candidates: list[XY], cs: list[XY], rs: list[float], areas: list[_Area]) -> list[XY]:
    """The candidate corners outside every disc and every area."""
    if not candidates:
        return []
    xy = np.array(candidates)
    ok = np.ones(len(xy), dtype=bool)
    for (cx, cy), r in zip(cs, rs, strict=True):
        ok &= np.hypot(xy[:, 0] - cx, xy[:, 1] - cy) >= r
    for area in areas:
        ok &= ~shapely.intersects_xy(area.keep_out, xy[:, 0], xy[:, 1])
    return [(float(x), float(y)) for x, y in xy[ok]]


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


def _clear(
    a: np.ndarray, b: np.ndarray, centres: list[XY], radii: list[float], areas: list[_Area]
) -> np.ndarray:
    """For each segment a[k]-b[k]: whether it keeps every disc's radius and stays out of
    every area.

    Worked out in arrays as far as it goes (a disc: the distance to each segment; an area:
    the segments' middles in it, the segments clear of its bounding box); shapely's
    segments are made only for the few left to look at, since every object made costs
    the garbage collector's time too (a server holds many).
    """
    ok = np.ones(len(a), dtype=bool)
    if not centres and not areas:
        return ok
    step = b - a
    length2 = np.maximum((step * step).sum(axis=1), 1e-18)
    for (cx, cy), r in zip(centres, radii, strict=True):
        t = np.clip(((cx - a[:, 0]) * step[:, 0] + (cy - a[:, 1]) * step[:, 1]) / length2, 0, 1)
        ok &= np.hypot(a[:, 0] + t * step[:, 0] - cx, a[:, 1] + t * step[:, 1] - cy) >= r * 0.999
    middles = (a + b) / 2
    for area in areas:
        ok &= ~shapely.intersects_xy(area.keep_out, middles[:, 0], middles[:, 1])
    low, high = np.minimum(a, b), np.maximum(a, b)
    for area in areas:
        x0, y0, x1, y1 = area.keep_out.bounds
        near = np.flatnonzero(
            ok & (low[:, 0] <= x1) & (high[:, 0] >= x0) & (low[:, 1] <= y1) & (high[:, 1] >= y0)
        )
        if len(near):
            lines = shapely.linestrings(np.stack([a[near], b[near]], axis=1))
            ok[near] = ~shapely.intersects(area.keep_out, lines)
    return ok
