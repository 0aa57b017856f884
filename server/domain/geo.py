"""Small geodesy: distances and local metric frames on the WGS84 sphere approximation."""

from __future__ import annotations

import math
from collections.abc import Sequence

EARTH_RADIUS_M = 6_371_008.8


def haversine_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    p1, p2 = math.radians(lat1), math.radians(lat2)
    dp = p2 - p1
    dl = math.radians(lon2 - lon1)
    a = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2 * EARTH_RADIUS_M * math.asin(min(1.0, math.sqrt(a)))


def lon_step(lon: float, lon0: float) -> float:
    """``lon - lon0`` the short way round, in [-180, 180): 179.9 to -179.9 is 0.2, east
    across the antimeridian, not 359.8 west (left as it is when already in range)."""
    step = lon - lon0
    return step if -180.0 <= step < 180.0 else (step + 180.0) % 360.0 - 180.0


def normal_lon(lon: float) -> float:
    """``lon`` in [-180, 180] (left as it is when it is; 180.5 is -179.5)."""
    return lon if -180.0 <= lon <= 180.0 else (lon + 180.0) % 360.0 - 180.0


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
