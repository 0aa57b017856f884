"""The one clock type: a function that tells the time (UTC-aware). Tests pass a fake one."""

from __future__ import annotations

from collections.abc import Callable
from datetime import datetime

Clock = Callable[[], datetime]


def said_time(said: datetime, now: datetime, earliest: datetime) -> datetime:
    """A time a vehicle says something began (its clock, corrected as it can), held
    between ``earliest`` and ``now``: a clock that is off cannot date it in the future,
    nor before the vehicle's instance began."""
    return max(earliest, min(said, now))
