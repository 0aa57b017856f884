"""Path planning for ``follow_path`` with ``plan: true``. Pure.

Each obstacle (another vehicle, with the safety radius around it) is a disc
in a local metric frame. A leg whose straight line keeps the clearance is
kept as is; otherwise the shortest way round is found on a visibility
graph: nodes on polygons circumscribing the discs, edges the segments that
keep the clearance from every disc, shortest path by Dijkstra.
"""

from __future__ import annotations

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

LatLon = tuple[float, float]
XY = tuple[float, float]


class NoPath(ValueError):
    """No path keeps the clearance (a waypoint is too close to an obstacle, or enclosed)."""


@dataclass(frozen=True)
class Obstacle:
    lat: float
    lon: float
    radius_m: float
    name: str = ""


def plan_path(
    start: LatLon | None, waypoints: Sequence[LatLon], obstacles: Sequence[Obstacle]
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
    for index, (lat, lon) in enumerate(waypoints):
        x, y = to_local(lat, lon, lat0, lon0)
        for (cx, cy), r, obstacle in zip(centres, radii, obstacles, strict=True):
            if math.hypot(x - cx, y - cy) < r:
                raise NoPath(
                    f"waypoint {index} is within {r:g} m of {obstacle.name or 'an obstacle'}"
                )
    points = [to_local(lat, lon, lat0, lon0) for lat, lon in waypoints]
    here = to_local(*origin, lat0, lon0) if start is not None else points[0]
    out: list[XY] = [] if start is not None else [points[0]]
    for goal in points if start is not None else points[1:]:
        out.extend(_leg(here, goal, centres, radii)[1:])
        here = goal
    return [from_local(x, y, lat0, lon0) for x, y in out]


def _leg(start: XY, goal: XY, centres: list[XY], radii: list[float]) -> list[XY]:
    # A disc the leg starts in is one the vehicle is leaving: it does not block this leg.
    keep = [
        i for i, (c, r) in enumerate(zip(centres, radii, strict=True)) if math.dist(start, c) >= r
    ]
    cs, rs = [centres[i] for i in keep], [radii[i] for i in keep]
    if _clear(np.array([start]), np.array([goal]), cs, rs)[0]:
        return [start, goal]
    nodes: list[XY] = [start, goal]
    for (cx, cy), r in zip(cs, rs, strict=True):
        ring = r * MARGIN / math.cos(math.pi / SIDES)
        for k in range(SIDES):
            angle = 2 * math.pi * k / SIDES
            node = (cx + ring * math.cos(angle), cy + ring * math.sin(angle))
            if all(math.dist(node, c) >= rr for c, rr in zip(cs, rs, strict=True)):
                nodes.append(node)
    pairs = [(i, j) for i in range(len(nodes)) for j in range(i + 1, len(nodes))]
    a = np.array([nodes[i] for i, _ in pairs])
    b = np.array([nodes[j] for _, j in pairs])
    clear = _clear(a, b, cs, rs)
    graph = nx.Graph()
    for (i, j), ok in zip(pairs, clear, strict=True):
        if ok:
            graph.add_edge(i, j, weight=math.dist(nodes[i], nodes[j]))
    try:
        route = nx.shortest_path(graph, 0, 1, weight="weight")
    except (nx.NetworkXNoPath, nx.NodeNotFound):
        raise NoPath("no way round the obstacles keeps the safety radius") from None
    return [nodes[i] for i in route]


def _clear(a: np.ndarray, b: np.ndarray, centres: list[XY], radii: list[float]) -> np.ndarray:
    """For each segment a[k]-b[k]: whether it keeps ``radius`` from every centre."""
    ok = np.ones(len(a), dtype=bool)
    if not centres:
        return ok
    lines = shapely.linestrings(np.stack([a, b], axis=1))
    for (cx, cy), r in zip(centres, radii, strict=True):
        ok &= shapely.distance(lines, shapely.Point(cx, cy)) >= r * 0.999
    return ok
