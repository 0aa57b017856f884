"""Path planning for ``follow_path`` with ``plan: true``. Pure.

Two kinds of obstacle, both in a local metric frame round the start:

- another vehicle: a disc (its position, the safety radius);
- a fixed obstacle (land, a pier, a no-go zone): a polygon grown by its clearance.

A leg whose straight line keeps every clearance is kept as is; otherwise the
shortest way round is found on a visibility graph: nodes on polygons
circumscribing the discs and on the outward corners of each grown polygon
(grown a little more, so the edges between corners stay clear), edges the
segments that keep every clearance, shortest path by Dijkstra.

Fixed obstacles join a leg's graph lazily: first those the straight leg
crosses, then any the route found crosses, until a route crosses none. A
harbour full of piers thus costs only the piers near the way.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import networkx as nx
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
#: Segments per quarter circle where a polygon is grown round a corner.
ARC_SEGMENTS = 4

LatLon = tuple[float, float]
XY = tuple[float, float]


class NoPath(ValueError):
    """No path keeps the clearance (a waypoint is too close to an obstacle, or enclosed)."""


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
        return bool(shapely.intersects_xy(self.keep_out, x, y))


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


def plan_path(
    start: LatLon | None,
    waypoints: Sequence[LatLon],
    obstacles: Sequence[Obstacle],
    zones: Sequence[Zone] = (),
) -> list[LatLon]:
    """The path through ``waypoints`` in order, from ``start`` (or the first waypoint).

    The result begins with the first point after ``start`` and ends with the last waypoint.
    """
    if not waypoints:
        raise NoPath("no waypoints")
    origin = start if start is not None else waypoints[0]
    lat0, lon0 = origin
    centres = [to_local(o.lat, o.lon, lat0, lon0) for o in obstacles]
    radii = [o.radius_m for o in obstacles]
    areas = [_Area(z, lat0, lon0) for z in zones]
    for index, (lat, lon) in enumerate(waypoints):
        x, y = to_local(lat, lon, lat0, lon0)
        for (cx, cy), r, obstacle in zip(centres, radii, obstacles, strict=True):
            if math.hypot(x - cx, y - cy) < r:
                raise NoPath(
                    f"waypoint {index} is within {r:g} m of {obstacle.name or 'an obstacle'}"
                )
        for area in areas:
            if area.holds(x, y):
                raise NoPath(
                    f"waypoint {index} is inside {area.label} "
                    f"or within its clearance of {area.clearance:g} m"
                )
    points = [to_local(lat, lon, lat0, lon0) for lat, lon in waypoints]
    here = to_local(*origin, lat0, lon0) if start is not None else points[0]
    out: list[XY] = [] if start is not None else [points[0]]
    for goal in points if start is not None else points[1:]:
        out.extend(_leg(here, goal, centres, radii, areas)[1:])
        here = goal
    return [from_local(x, y, lat0, lon0) for x, y in out]


def _leg(
    start: XY, goal: XY, centres: list[XY], radii: list[float], areas: list[_Area]
) -> list[XY]:
    # An obstacle the leg starts in is one the vehicle is leaving: it does not block this leg.
    keep = [
        i for i, (c, r) in enumerate(zip(centres, radii, strict=True)) if math.dist(start, c) >= r
    ]
    cs, rs = [centres[i] for i in keep], [radii[i] for i in keep]
    left = [a for a in areas if not a.holds(*start)]
    active: list[_Area] = []
    while True:
        route = _route(start, goal, cs, rs, active)
        line = shapely.LineString(route)
        crossed = [a for a in left if a not in active and a.keep_out.intersects(line)]
        if not crossed:
            return route
        active.extend(crossed)


def _route(start: XY, goal: XY, cs: list[XY], rs: list[float], areas: list[_Area]) -> list[XY]:
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
        candidates.extend(area.corners)
    nodes: list[XY] = [start, goal]
    for node in candidates:
        if all(math.dist(node, c) >= rr for c, rr in zip(cs, rs, strict=True)) and not any(
            a.holds(*node) for a in areas
        ):
            nodes.append(node)
    first, second = np.triu_indices(len(nodes), k=1)
    xy = np.array(nodes)
    clear = _clear(xy[first], xy[second], cs, rs, areas)
    first, second = first[clear], second[clear]
    lengths = np.hypot(*(xy[first] - xy[second]).T)
    graph = nx.Graph()
    graph.add_weighted_edges_from(
        zip(first.tolist(), second.tolist(), lengths.tolist(), strict=True)
    )
    try:
        route = nx.shortest_path(graph, 0, 1, weight="weight")
    except (nx.NetworkXNoPath, nx.NodeNotFound):
        raise NoPath("no way round the obstacles keeps the clearance") from None
    return [nodes[i] for i in route]


def _clear(
    a: np.ndarray, b: np.ndarray, centres: list[XY], radii: list[float], areas: list[_Area]
) -> np.ndarray:
    """For each segment a[k]-b[k]: whether it keeps every disc's radius and stays out of
    every area."""
    ok = np.ones(len(a), dtype=bool)
    if not centres and not areas:
        return ok
    lines = shapely.linestrings(np.stack([a, b], axis=1))
    for (cx, cy), r in zip(centres, radii, strict=True):
        ok &= shapely.distance(lines, shapely.Point(cx, cy)) >= r * 0.999
    middles = (a + b) / 2
    for area in areas:
        ok &= ~shapely.intersects_xy(area.keep_out, middles[:, 0], middles[:, 1])
        ok[ok] = ~shapely.intersects(area.keep_out, lines[ok])
    return ok
