"""Telemetry's views: a vehicle's track in a time window (downsampled on request) and
its samples page by page, each ``seq`` once, from the stored buckets and the samples
not yet written (:class:`server.services.telemetry.TelemetryService` is one)."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from typing import Any

from server.domain.track import TRACK_PAGE_CAP, cut_page, simplify
from server.storage.backends import Doc
from server.storage.telemetry import TelemetryRepo, distinct_samples

#: Points read from the store for one downsampled track; past it the track is paged.
SIMPLIFY_INPUT_CAP = 500_000
#: Buckets read per query when paging by ``seq`` on MongoDB.
PAGE_BUCKETS = 20
#: Fields of a sample shown in a track (``data`` is left to the telemetry page).
TRACK_FIELDS = ("seq", "lat", "lon", "depth_m", "heading_deg", "speed_mps", "battery_pct")


@dataclass(slots=True)
class TrackResult:
    vehicle_id: str
    points: list[dict[str, Any]]  # ts as datetime, in ts order
    truncated: bool
    next_from: datetime | None


class TelemetryViews:
    """The read side of the telemetry service: what it stored and what it holds."""

    repo: TelemetryRepo

    def _tail(self, vehicle_id: str) -> list[Doc]:
        """The samples not yet in a bucket (snapshot, taken before reading buckets)."""
        raise NotImplementedError

    async def track(
        self,
        vehicle_id: str,
        start: datetime,
        end: datetime,
        max_points: int | None = None,
        *,
        cap: int | None = None,
    ) -> TrackResult:
        """Points with ``start <= ts < end`` in ``ts`` order; downsampled to ``max_points``.

        At most ``cap`` points are read (10,000 without ``max_points``); past it the
        result is ``truncated`` and ``next_from`` starts the next page.
        """
        tail = self._tail(vehicle_id)
        buckets = await self.repo.in_window(vehicle_id, start, end)
        points: list[dict[str, Any]] = []
        for s in distinct_samples(buckets):
            ts = s["ts"]
            if start <= ts < end:
                points.append(_point(s, ts))
        # A bucket written since the tail was taken may be in both: its samples count once.
        stored_high = max((b["max_seq"] for b in buckets), default=-1)
        for s in tail:
            ts = s["ts"]
            if start <= ts < end and s["seq"] > stored_high:
                points.append(_point(s, ts))
        points.sort(key=lambda p: (p["ts"], p["seq"]))
        if cap is None:
            cap = TRACK_PAGE_CAP if max_points is None else SIMPLIFY_INPUT_CAP
        count, next_from = cut_page([p["ts"] for p in points], cap)
        points = points[:count]
        if max_points is not None:
            keep = simplify([p["lat"] for p in points], [p["lon"] for p in points], max_points)
            points = [points[i] for i in keep]
        return TrackResult(vehicle_id, points, next_from is not None, next_from)

    async def page(
        self,
        vehicle_id: str,
        *,
        after_seq: int = -1,
        start: datetime | None = None,
        end: datetime | None = None,
        limit: int = 1000,
    ) -> tuple[list[Doc], int | None]:
        """Stored samples with ``seq > after_seq`` (and ``start <= ts < end``) in ``seq`` order."""
        tail = self._tail(vehicle_id)
        out: list[Doc] = []

        def take(s: Doc) -> bool:
            ts = s["ts"]
            if (start is None or ts >= start) and (end is None or ts < end):
                out.append({**s, "ts": ts})
            return len(out) >= limit

        cursor = after_seq  # every seq up to here is read
        full = False
        while not full:
            buckets = await self.repo.after_seq(
                vehicle_id, cursor, limit=PAGE_BUCKETS, start=start, end=end
            )
            if not buckets:
                break
            # Of copies in this batch, the first stored; one from an earlier batch was shown.
            for s in distinct_samples(buckets):
                if s["seq"] > cursor and take(s):
                    full = True
                    break
            cursor = max(cursor, *(b["max_seq"] for b in buckets))
        if not full:
            last = out[-1]["seq"] if out else after_seq
            for s in tail:
                if s["seq"] > max(last, cursor) and take(s):
                    break
        next_after = out[-1]["seq"] if len(out) >= limit else None
        return out, next_after


def _point(sample: Doc, ts: datetime) -> dict[str, Any]:
    point: dict[str, Any] = {"ts": ts}
    for name in TRACK_FIELDS:
        value = sample.get(name)
        if value is not None:
            point[name] = value
    return point
