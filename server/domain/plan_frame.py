"""The planner's obstacles in a local metric frame round a start (``planning``): another
vehicle a disc, a fixed obstacle or a zone a polygon grown by its clearance; whether
segments keep clear of them; and two checks of a route against fixed obstacles. Pure."""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
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
#: A point less than this (m) inside a zone's edge is on it (the zones' check of a route
#: allows a rounding's width there, ``zones.EDGE_DEG``: about 2 mm).
EDGE_M = 3e-3
LatLon = tuple[float, float]
XY = tuple[float, float]

#: Segments per quarter circle where a polygon is grown round a corner.
ARC_SEGMENTS = 4


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


class LocalArea:
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


def outside(
    candidates: list[XY], cs: list[XY], rs: list[float], areas: list[LocalArea]
) -> list[XY]:
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


def clear(
    a: np.ndarray, b: np.ndarray, centres: list[XY], radii: list[float], areas: list[LocalArea]
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
