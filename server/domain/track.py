"""Tracks for replay: shape-keeping downsampling and the page cut. Pure.

Downsampling is Visvalingam-Whyatt: repeatedly drop the point whose triangle
with its two neighbours has the smallest area (the one that changes the
shape least) until ``max_points`` remain; of equal areas, the point whose
neighbours are nearest in the track, so that a straight run keeps points
spread along it. The first and last points are
always kept. Areas are computed in a local equirectangular frame (degrees of
longitude scaled by the cosine of the mean latitude; longitudes unwrapped
across the antimeridian), which is plenty to rank points of one track.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Sequence
from datetime import datetime, timedelta

from server.domain.geo import unwrap

#: Points returned without ``max_points`` before a track page is cut.
TRACK_PAGE_CAP = 10_000


def simplify(lat: Sequence[float], lon: Sequence[float], max_points: int) -> list[int]:
    """Indices (rising) of at most ``max_points`` points that keep the track's shape.

    Always keeps the first and the last point (so ``max_points`` below 2 acts as 2).
    """
    n = len(lat)
    if len(lon) != n:
        raise ValueError("lat and lon differ in length")
    if n <= max(max_points, 2):
        return list(range(n))
    scale = math.cos(math.radians(sum(lat) / n))
    xs = [x * scale for x in unwrap(lon)]
    ys = list(lat)

    def area(a: int, b: int, c: int) -> float:
        return abs((xs[b] - xs[a]) * (ys[c] - ys[a]) - (xs[c] - xs[a]) * (ys[b] - ys[a]))

    prev = list(range(-1, n - 1))
    nxt = list(range(1, n + 1))
    areas = [math.inf] * n
    for i in range(1, n - 1):
        areas[i] = area(i - 1, i, i + 1)
    # Of points that change the shape as little (a straight run, a vehicle at rest: all
    # zero), the one whose neighbours are nearest in the track goes first: what is kept
    # stays spread along it, not piled at its end (the index broke ties before).
    heap = [(areas[i], 2, i) for i in range(1, n - 1)]
    heapq.heapify(heap)
    removed = [False] * n
    remaining = n
    target = max(max_points, 2)
    while remaining > target:
        value, span, i = heapq.heappop(heap)
        if removed[i] or value != areas[i] or span != nxt[i] - prev[i]:
            continue  # a stale entry: the point's area or neighbours changed since
        removed[i] = True
        remaining -= 1
        p, q = prev[i], nxt[i]
        nxt[p], prev[q] = q, p
        for j in (p, q):
            if 0 < j < n - 1:
                # Never below the area just removed: keeps the elimination order monotone.
                areas[j] = max(area(prev[j], j, nxt[j]), value)
                heapq.heappush(heap, (areas[j], nxt[j] - prev[j], j))
    return [i for i in range(n) if not removed[i]]


def cut_page(times: Sequence[datetime], cap: int) -> tuple[int, datetime | None]:
    """Where to cut ``ts``-sorted points for a page of at most ``cap`` points.

    Returns ``(count, next_from)``: the first ``count`` points form the page and
    the next page starts at ``next_from`` (inclusive), or ``None`` when all fit.
    The cut never splits points sharing one ``ts``, so paging neither repeats
    nor skips a point; only when more than ``cap`` points share a single ``ts``
    are the extra ones skipped, and the next page starts a millisecond later.
    """
    if len(times) <= cap:
        return len(times), None
    boundary = times[cap]
    count = cap
    while count > 0 and times[count - 1] == boundary:
        count -= 1
    if count == 0:
        return cap, boundary + timedelta(milliseconds=1)
    return count, boundary
