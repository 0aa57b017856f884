"""A vehicle's link delay, from the timing its calls carry. Pure.

A vehicle stamps ``update_param`` with ``sent_at`` (its clock) and the offset
it estimates between the server's clock and its own (``clock_offset_s``,
NTP-style from the ``server_time`` of its calls: ``vehicle_client.clock``).
The one-way delay is the arrival by the server's clock less the send time
moved onto the server's clock. :class:`LinkDelay` smooths it per instance
for the vehicle's view and says when the view is worth telling again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime

#: Weight of a new measure in the smoothed delay (an exponential moving average).
SMOOTHING = 0.25
#: A delay beyond this either way is a clock gone wrong, not a delay: left out.
MAX_DELAY_S = 60.0
#: The view is told again when the smoothed delay moved by this much (ms) and by this
#: fraction of the value told, at most once per ``TELL_EVERY_S`` per vehicle.
TELL_MIN_MS = 5.0
TELL_FRACTION = 0.25
TELL_EVERY_S = 5.0


def one_way_delay_s(
    sent_at: datetime, received_at: datetime, clock_offset_s: float | None
) -> float:
    """Seconds from ``sent_at`` (the vehicle's clock) to ``received_at`` (the server's),
    the vehicle's clock moved by ``clock_offset_s`` (server minus vehicle; None: the two
    clocks are taken as in step). May come out below zero when the offset is off by more
    than the delay: the caller clamps."""
    offset = clock_offset_s or 0.0
    return (received_at - sent_at).total_seconds() - offset


@dataclass(slots=True)
class LinkDelay:
    """One instance's link as the server last measured it (smoothed, in ms)."""

    delay_ms: float | None = None
    rtt_ms: float | None = None
    told_ms: float | None = None
    told_at: float = -math.inf

    def observe(self, delay_s: float, rtt_s: float | None, now: float) -> bool:
        """Take a measure (``now``: a monotonic time in seconds); whether the view should be
        told again (the first measure, or a move past the thresholds, not too often)."""
        if not -MAX_DELAY_S <= delay_s <= MAX_DELAY_S:
            return False
        delay_ms = max(0.0, delay_s) * 1000.0
        self.delay_ms = (
            delay_ms
            if self.delay_ms is None
            else self.delay_ms + SMOOTHING * (delay_ms - self.delay_ms)
        )
        if rtt_s is not None:
            rtt_ms = rtt_s * 1000.0
            self.rtt_ms = (
                rtt_ms if self.rtt_ms is None else self.rtt_ms + SMOOTHING * (rtt_ms - self.rtt_ms)
            )
        if now - self.told_at < TELL_EVERY_S:
            return False
        told = self.told_ms
        moved = told is None or abs(self.delay_ms - told) >= max(TELL_MIN_MS, TELL_FRACTION * told)
        if moved:
            self.told_ms, self.told_at = self.delay_ms, now
        return moved

    def view(self) -> tuple[float | None, float | None]:
        """``(link_delay_ms, link_rtt_ms)``, rounded to 0.1 ms."""
        return _round(self.delay_ms), _round(self.rtt_ms)


def _round(value: float | None) -> float | None:
    return None if value is None else round(value, 1)
