"""Small geodesy: distances and local metric frames on the WGS84 sphere approximation."""

from __future__ import annotations

import math
from collections.abc import Sequence

from fleet_protocol import lon_step, normal_lon

__all__ = [
    "EARTH_RADIUS_M",
    "from_local",
    "haversine_m",
    "lon_step",
    "normal_lon",
    "to_local",
    "unwrap",
]

EARTH_RADIUS_M = 6_371_008.8


def haversine_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    p1, p2 = math.radians(lat1), math.radians(lat2)
    dp = p2 - p1
    dl = math.radians(lon2 - lon1)
    a = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2 * EARTH_RADIUS_M * math.asin(min(1.0, math.sqrt(a)))


def unwrap(lons: Sequence[float]) -> list[float]:
    """Longitudes made continuous: each the one before plus the short step to it (the
    first as it is), so a line across the antimeridian runs past 180 instead of back
    round the globe."""
    out: list[float] = []
    for lon in lons:
        out.append(out[-1] + lon_step(lon, out[-1]) if out else lon)
    return out


def to_local(lat: float, lon: float, lat0: float, lon0: float) -> tuple[float, float]:
    """East/north metres of (lat, lon) from the origin (lat0, lon0), the short way round
    in longitude; fine for a few km."""
    x = math.radians(lon_step(lon, lon0)) * EARTH_RADIUS_M * math.cos(math.radians(lat0))
    y = math.radians(lat - lat0) * EARTH_RADIUS_M
    return x, y


def from_local(x: float, y: float, lat0: float, lon0: float) -> tuple[float, float]:
    """:func:`to_local` undone; the longitude in [-180, 180]."""
    lat = lat0 + math.degrees(y / EARTH_RADIUS_M)
    lon = lon0 + math.degrees(x / (EARTH_RADIUS_M * math.cos(math.radians(lat0))))
    return lat, normal_lon(lon)
