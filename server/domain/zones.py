"""Operating areas and no-go zones: where a vehicle may be sent, and where it is. Pure.

A no-go zone applies to every vehicle, or to those it lists; an operating area holds the
vehicles it lists (a vehicle with no area is held by none). A target or a route is
refused when it touches a no-go zone of the vehicle or leaves all of its areas; a
position is in breach when it is inside such a zone or outside all its areas.
Geometry is planar in degrees (longitude, latitude), which is what GeoJSON draws and
fine at the size of a harbour or a survey area.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Literal

import shapely
import shapely.affinity
from shapely.geometry import LineString, Point, Polygon
from shapely.geometry.base import BaseGeometry
from shapely.ops import unary_union

from server.domain.geo import lon_step, unwrap
from server.domain.plan_frame import Zone
from server.errors import Invalid

ZoneKind = Literal["no_go", "operating_area"]
#: (lat, lon) in degrees.
LatLon = tuple[float, float]
#: A no-go zone's edge is this wide (degrees, about 2 mm): a point that far inside it,
#: which the planner allows (a clearance less ``planning.TOUCH_M``), is on the edge.
EDGE_DEG = 2e-8
#: How far (degrees, about 5 km) the frame round an operating area reaches: the planner
#: keeps a path inside the area by treating this frame, with the area as its hole, as
#: an obstacle.
AREA_FRAME_DEG = 0.05
_NONE: frozenset[str] = frozenset()


@dataclass(frozen=True)
class Area:
    """One zone: its rings as (lat, lon) positions, the first the outline, the rest holes."""

    zone_id: str
    name: str
    kind: ZoneKind
    rings: tuple[tuple[LatLon, ...], ...]
    vehicles: frozenset[str] = frozenset()
    clearance_m: float = 0.0

    @cached_property
    def shape(self) -> Polygon:
        """The zone in (lon, lat) degrees, each ring's longitudes continuous (a zone across
        the antimeridian runs past 180), the holes on the outline's side of it."""
        shell, *holes = ([(lon, lat) for lat, lon in ring] for ring in self.rings)
        outline = _continuous(shell)
        west = outline[0][0]
        inner = []
        for hole in holes:
            ring = _continuous(hole)
            turn = ring[0][0] - (west + lon_step(ring[0][0], west))
            inner.append([(lon - turn, lat) for lon, lat in ring])
        return Polygon(outline, inner)

    @cached_property
    def inside(self) -> Polygon:
        """The zone less a rounding's width at its edge (as the planner's clearances are)."""
        inner = self.shape.buffer(-EDGE_DEG)
        return inner if not inner.is_empty else self.shape

    @cached_property
    def _prepared_inside(self) -> Polygon:
        shapely.prepare(self.inside)
        return self.inside

    @cached_property
    def _prepared_shape(self) -> Polygon:
        shapely.prepare(self.shape)
        return self.shape

    @cached_property
    def _lons(self) -> tuple[float, float]:
        west, _, east, _ = self.shape.bounds
        return west, east

    def turns(self, west: float, east: float) -> list[float]:
        """The whole turns (0, -360, 360 degrees) by which the zone, turned, meets the
        longitudes from ``west`` to ``east``: a zone and a route on either side of the
        antimeridian are compared on one side of it. Only 0 for most."""
        low, high = self._lons
        return [t for t in (0.0, -360.0, 360.0) if west <= high + t and east >= low + t]

    def copies(self, west: float, east: float) -> list[Polygon]:
        """The zone, turned by each of :meth:`turns`."""
        return [shapely.affinity.translate(self.shape, t) for t in self.turns(west, east)]

    def holds(self, point: LatLon) -> bool:
        """Whether a position is inside (as :meth:`enters` has it for a point): no
        geometry object made, the zone prepared once (the watch asks for every sample)."""
        lat, lon = point
        inside = self._prepared_inside
        return any(shapely.contains_xy(inside, lon - t, lat) for t in self.turns(lon, lon))

    def covers(self, point: LatLon) -> bool:
        """Whether a position is inside or on the edge."""
        lat, lon = point
        shape = self._prepared_shape
        return any(shapely.intersects_xy(shape, lon - t, lat) for t in self.turns(lon, lon))

    def enters(self, geometry: BaseGeometry) -> bool:
        """Whether ``geometry`` (longitudes continuous) reaches inside (its edge touched
        is not inside, nor a millimetre or two past it: rounding)."""
        west, _, east, _ = geometry.bounds
        return any(
            self.inside.relate_pattern(
                shapely.affinity.translate(geometry, -t) if t else geometry, "T********"
            )
            for t in self.turns(west, east)
        )

    def applies_to(self, vehicle_id: str) -> bool:
        if self.kind == "no_go":
            return not self.vehicles or vehicle_id in self.vehicles
        return vehicle_id in self.vehicles


@dataclass(frozen=True)
class Violation:
    """Why a target, a route or a position is refused: the zone, and a sentence."""

    zone_id: str
    name: str
    kind: ZoneKind
    message: str


@dataclass(frozen=True)
class ZoneSet:
    """Every zone the server knows, at one version of the set."""

    areas: tuple[Area, ...] = ()
    version: int = 0
    _cache: dict[str, tuple[tuple[Area, ...], tuple[Area, ...]]] = field(
        default_factory=dict, compare=False, repr=False
    )

    def of(self, vehicle_id: str) -> tuple[tuple[Area, ...], tuple[Area, ...]]:
        """The vehicle's no-go zones and its operating areas."""
        found = self._cache.get(vehicle_id)
        if found is None:
            mine = [a for a in self.areas if a.applies_to(vehicle_id)]
            found = (
                tuple(a for a in mine if a.kind == "no_go"),
                tuple(a for a in mine if a.kind == "operating_area"),
            )
            self._cache[vehicle_id] = found
        return found

    def no_go(self, vehicle_id: str) -> tuple[Area, ...]:
        return self.of(vehicle_id)[0]


def route_violation(
    zones: ZoneSet, vehicle_id: str, start: LatLon | None, points: Sequence[LatLon]
) -> Violation | None:
    """Why the vehicle, at ``start`` (None: unknown), may not drive through ``points``
    (straight legs, each the short way round in longitude). A vehicle already inside a
    no-go zone, or outside its areas, may leave: the leg it starts on is not held
    against it until it is out (or in), but from there on the route may not come back
    in (or leave again)."""
    if not points:
        return None
    no_go, areas = zones.of(vehicle_id)
    route = _continuous_route([start, *points] if start is not None else list(points))
    here: Point | None = None  # the vehicle, and the leg it starts on
    first = LineString()
    sent = route
    if start is not None:
        (lat, lon), *sent = route
        here, first = Point(lon, lat), LineString([(lon, lat), (sent[0][1], sent[0][0])])
    whole = _line(route)
    for area in no_go:
        way = whole
        if here is not None and area.enters(here):
            out = first.difference(unary_union(area.copies(*_lons(first))))
            way = _from(first, out, sent, 0.0)
        if not area.enters(way):
            continue
        hit = [k for k, (lat, lon) in enumerate(sent) if area.enters(Point(lon, lat))]
        if not hit:
            what = "the route crosses"
        elif len(points) == 1:
            what = "the target is in"
        else:
            what = f"point {hit[0]} of the route is in"
        return Violation(area.zone_id, area.name, "no_go", f"{what} no-go zone {area.name}")
    if areas:
        held = unary_union([c for a in areas for c in a.copies(*_lons(whole))])
        way = whole
        if here is not None and not held.covers(here):
            # Past the edge by a rounding's width: the point where it comes in is not out.
            way = _from(first, first.intersection(held), sent, EDGE_DEG)
        if not held.covers(way):
            names = ", ".join(a.name for a in areas)
            last = Point(sent[-1][1], sent[-1][0])
            what = "target is outside" if not held.covers(last) else "route leaves"
            return Violation(
                areas[0].zone_id,
                areas[0].name,
                "operating_area",
                f"the {what} the vehicle's operating area ({names})",
            )
    return None


def _line(route: Sequence[LatLon]) -> LineString | Point:
    if len(route) == 1:
        return Point(route[0][1], route[0][0])
    return LineString([(lon, lat) for lat, lon in route])


def _from(
    first: LineString, beyond: BaseGeometry, points: Sequence[LatLon], past: float
) -> LineString | Point:
    """The route from where its first leg (``first``, from the vehicle) first reaches
    ``beyond`` (the part of the leg out of the zone the vehicle is in, or in the areas
    it is out of), ``past`` degrees further on; all of it when the leg never does (its
    end, the first point, is then judged)."""
    if beyond.is_empty:
        return _line(points)
    coords = shapely.points(shapely.get_coordinates(beyond))
    reached = float(shapely.line_locate_point(first, coords).min())
    at = min(reached + past, first.length)
    if at >= first.length:
        return _line(points)
    x, y = first.interpolate(at).coords[0]
    return _line([(y, x), *points])


def _continuous(ring: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    """(lon, lat) points with their longitudes made continuous."""
    return list(zip(unwrap([lon for lon, _ in ring]), [lat for _, lat in ring], strict=True))


def _continuous_route(route: Sequence[LatLon]) -> list[LatLon]:
    """(lat, lon) points with their longitudes made continuous: each leg the short way."""
    return list(zip([lat for lat, _ in route], unwrap([lon for _, lon in route]), strict=True))


def _lons(geometry: BaseGeometry) -> tuple[float, float]:
    west, _, east, _ = geometry.bounds
    return west, east


def breaches(zones: ZoneSet, vehicle_id: str, point: LatLon) -> frozenset[str]:
    """Where the vehicle at ``point`` should not be: the no-go zones it is in, and
    ``area:<vehicle>`` when it is outside all of its operating areas."""
    no_go, areas = zones.of(vehicle_id)
    if not no_go and not areas:
        return _NONE
    out = {a.zone_id for a in no_go if a.holds(point)}
    if areas and not any(a.covers(point) for a in areas):
        out.add(f"area:{vehicle_id}")
    return frozenset(out)


def command_targets(kind: str, args: dict[str, object]) -> list[LatLon]:
    """The positions a command sends the vehicle to, in order (none for ``stop`` or a
    ``keep_station`` where the vehicle is)."""
    if kind == "go_to":
        return [(float(args["lat"]), float(args["lon"]))]  # type: ignore[arg-type]
    if kind == "keep_station" and args.get("lat") is not None:
        return [(float(args["lat"]), float(args["lon"]))]  # type: ignore[arg-type]
    if kind == "follow_path":
        route = args.get("path") or args.get("waypoints") or []
        return [(float(p["lat"]), float(p["lon"])) for p in route]  # type: ignore[attr-defined]
    return []


def command_violation(
    zones: ZoneSet, vehicle_id: str, kind: str, args: dict[str, object], start: LatLon | None
) -> Violation | None:
    """Why the command may not be sent to the vehicle at ``start``, if it may not: where
    it sends the vehicle, and the straight way there from ``start``."""
    return route_violation(zones, vehicle_id, start, command_targets(kind, args))


def closest_routes(
    routes: dict[str, Sequence[LatLon]], separation_m: float
) -> tuple[str, str, float] | None:
    """Two routes that come within ``separation_m`` of each other (and how close), or
    None. Distances in metres, on a local flat frame round the routes' mean latitude."""
    points = [p for route in routes.values() for p in route]
    if len(routes) < 2 or not points:
        return None
    lat0 = sum(p[0] for p in points) / len(points)
    kx = 111_320.0 * math.cos(math.radians(lat0))
    ky = 110_540.0
    lon0 = points[0][1]  # longitudes the short way from it: routes across the antimeridian

    def east(lon: float) -> float:
        return (lon0 + lon_step(lon, lon0)) * kx

    shapes = {
        name: (
            LineString([(east(lon), lat * ky) for lat, lon in route])
            if len(route) > 1
            else Point(east(route[0][1]), route[0][0] * ky)
        )
        for name, route in routes.items()
        if route
    }
    names = sorted(shapes)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            distance = shapes[a].distance(shapes[b])
            if distance < separation_m:
                return a, b, distance
    return None


def keep_out(zones: ZoneSet, vehicle_id: str) -> list[Zone]:
    """What a path planned for the vehicle keeps clear of: its no-go zones (at their
    clearance), and the outside of its operating area (a frame round the area with the
    area as its hole; each hole of the area, an island, as an obstacle of its own).
    Several areas that do not make one polygon are left to the route check."""
    no_go, areas = zones.of(vehicle_id)
    out = [Zone(a.rings, a.clearance_m, f"no-go zone {a.name}") for a in no_go]
    if areas:
        held = unary_union([a.shape for a in areas])
        if isinstance(held, Polygon):
            x0, y0, x1, y1 = held.bounds
            d = AREA_FRAME_DEG
            frame = ((y0 - d, x0 - d), (y0 - d, x1 + d), (y1 + d, x1 + d), (y1 + d, x0 - d))
            shell = tuple((lat, lon) for lon, lat in held.exterior.coords)
            name = "the outside of the operating area " + ", ".join(a.name for a in areas)
            out.append(Zone((frame, shell), 0.0, name))
            for hole in held.interiors:
                island = tuple((lat, lon) for lon, lat in hole.coords)
                out.append(Zone((island,), 0.0, name))
    return out


def zone_changes(zone: Mapping[str, Any], wanted: Mapping[str, Any]) -> dict[str, Any]:
    """What a patch changes of a zone: each field of ``wanted`` (None: not given) whose
    value is not the zone's already; empty when nothing changes (the zone keeps its
    version). A zone's kind cannot change (delete it and draw another): a ``kind`` other
    than its own is refused, naming the field."""
    kind = wanted.get("kind")
    if kind is not None and kind != zone["kind"]:
        message = (
            f"a zone's kind cannot change (this one is {zone['kind']}): "
            "delete it and create a zone of the other kind"
        )
        raise Invalid(message, details=[{"field": "kind", "message": message}])
    return {
        name: value
        for name, value in wanted.items()
        if name != "kind" and value is not None and value != zone.get(name)
    }
