"""Local flat-earth frame: east/north metres around a reference point (pure).

Good to a few centimetres over a few kilometres, which is the scale a
vehicle works at between two reference points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

EARTH_RADIUS_M = 6_378_137.0


def _wrapped(degrees: float) -> float:
    """An angle in degrees brought into [-180, 180). This module is the standard library's
    alone (the ROS node imports it on the system's Python): no ``fleet_protocol`` here."""
    return (degrees + 180.0) % 360.0 - 180.0


@dataclass(frozen=True)
class LocalFrame:
    """East-north-up metres around ``(lat0, lon0)``."""

    lat0: float
    lon0: float

    def to_enu(self, lat: float, lon: float) -> tuple[float, float]:
        step = lon - self.lon0
        if not -180.0 <= step < 180.0:  # the short way: 179.9 E to 179.9 W is 0.2 east
            step = _wrapped(step)
        east = math.radians(step) * EARTH_RADIUS_M * math.cos(math.radians(self.lat0))
        north = math.radians(lat - self.lat0) * EARTH_RADIUS_M
        return east, north

    def to_latlon(self, east: float, north: float) -> tuple[float, float]:
        lat = self.lat0 + math.degrees(north / EARTH_RADIUS_M)
        lon = self.lon0 + math.degrees(east / (EARTH_RADIUS_M * math.cos(math.radians(self.lat0))))
        # east of 180 is the far west: a longitude the wire takes (within ±180)
        return lat, lon if -180.0 <= lon <= 180.0 else _wrapped(lon)


def distance_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Great-circle distance (haversine)."""
    p1, p2 = math.radians(lat1), math.radians(lat2)
    dp, dl = p2 - p1, math.radians(lon2 - lon1)
    a = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2 * EARTH_RADIUS_M * math.asin(min(1.0, math.sqrt(a)))


def heading_deg(east: float, north: float) -> float:
    """Compass heading of a direction vector: degrees clockwise from north, in [0, 360)."""
    return math.degrees(math.atan2(east, north)) % 360.0


def wrap_deg(angle: float) -> float:
    """An angle difference folded into (-180, 180]."""
    folded = (angle + 180.0) % 360.0 - 180.0
    return 180.0 if folded == -180.0 else folded
