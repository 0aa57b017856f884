"""Collision forecast: each vehicle's course and speed projected ahead, and the pairs that
come within the separation. Pure.

Each vehicle moves on a straight line at its reported speed and heading (degrees
clockwise from north) from its latest position. For a pair, the time of closest
approach is where the distance between the two lines is least, clamped to
``[0, horizon_s]``; the pair is at risk when that distance is below the separation.
Positions go into one local flat frame (metres east and north of the fleet's mean
position), fine over the tens of kilometres a fleet spans.

All pairs are looked at, in blocks of rows as numpy arrays, after a cheap test that
drops the pairs too far apart to meet within the horizon at their speeds: 1,000
vehicles are half a million pairs, a few milliseconds (``make bench``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from server.domain.geo import EARTH_RADIUS_M, normal_lon

#: Rows of pairs worked out at once (a block of ROWS x n distances in memory).
ROWS = 256


@dataclass(frozen=True)
class Course:
    """A vehicle as the forecast sees it."""

    key: str
    lat: float
    lon: float
    speed_mps: float
    heading_deg: float


@dataclass(frozen=True)
class Risk:
    """Two vehicles forecast to come within the separation: when, how close, where."""

    a: str
    b: str
    in_s: float
    closest_m: float
    distance_now_m: float
    where: tuple[float, float]  # (lat, lon) half-way between them then


def forecast(courses: Sequence[Course], horizon_s: float, separation_m: float) -> list[Risk]:
    """The pairs forecast to come within ``separation_m`` in the next ``horizon_s``, each
    once (``a`` < ``b``), nearest first."""
    n = len(courses)
    if n < 2 or separation_m <= 0:
        return []
    lat = np.array([c.lat for c in courses])
    lon = _seamless(np.array([c.lon for c in courses]))
    lat0, lon0 = float(lat.mean()), float(lon.mean())
    k = math.pi / 180 * EARTH_RADIUS_M
    x = (lon - lon0) * k * math.cos(math.radians(lat0))
    y = (lat - lat0) * k
    speed = np.array([max(0.0, c.speed_mps) for c in courses])
    heading = np.radians([c.heading_deg for c in courses])
    vx, vy = speed * np.sin(heading), speed * np.cos(heading)
    reach = speed * horizon_s
    found: list[tuple[int, int, float, float, float]] = []
    for lo in range(0, n - 1, ROWS):
        i = np.arange(lo, min(lo + ROWS, n - 1))[:, None]
        j = np.arange(n)[None, :]
        dx, dy = x[j] - x[i], y[j] - y[i]
        now2 = dx * dx + dy * dy
        limit = separation_m + reach[i] + reach[j]
        near = (j > i) & (now2 < limit * limit)
        if not near.any():
            continue
        ii, jj = np.nonzero(near)
        ii, jj = ii + lo, jj
        px, py = x[jj] - x[ii], y[jj] - y[ii]
        ux, uy = vx[jj] - vx[ii], vy[jj] - vy[ii]
        u2 = ux * ux + uy * uy
        t = np.where(u2 > 1e-12, -(px * ux + py * uy) / np.maximum(u2, 1e-12), 0.0)
        t = np.clip(t, 0.0, horizon_s)
        cx, cy = px + ux * t, py + uy * t
        closest = np.hypot(cx, cy)
        hit = np.flatnonzero(closest < separation_m)
        for h in hit:
            found.append(
                (
                    int(ii[h]),
                    int(jj[h]),
                    float(t[h]),
                    float(closest[h]),
                    float(np.hypot(px[h], py[h])),
                )
            )
    risks = []
    for a, b, t_s, closest_m, now_m in found:
        mx = (x[a] + vx[a] * t_s + x[b] + vx[b] * t_s) / 2
        my = (y[a] + vy[a] * t_s + y[b] + vy[b] * t_s) / 2
        where = (lat0 + my / k, normal_lon(lon0 + mx / (k * math.cos(math.radians(lat0)))))
        first, second = sorted((courses[a].key, courses[b].key))
        risks.append(Risk(first, second, t_s, closest_m, now_m, where))
    risks.sort(key=lambda r: (r.closest_m, r.a, r.b))
    return risks


def _seamless(lon: np.ndarray) -> np.ndarray:
    """The fleet's longitudes made continuous where it has vehicles: as they are when
    they span at most 180 degrees (no two are nearer the other way round); else turned
    into one 360-degree range whose seam lies in the widest gap between them, so two
    boats either side of the antimeridian are near, not a world apart."""
    if len(lon) == 0 or float(lon.max() - lon.min()) <= 180.0:
        return lon
    round_ = np.sort(np.mod(lon, 360.0))
    gaps = np.diff(np.append(round_, round_[0] + 360.0))
    widest = int(np.argmax(gaps))
    seam = float(round_[widest] + gaps[widest] / 2)
    return np.asarray(np.mod(lon - seam, 360.0) + seam)
