"""Long background passes give the event loop back every few milliseconds.

A pass that writes thousands of records (telemetry buckets aging out
together, contact written back for every vehicle) would otherwise hold the
loop for its whole length, and every socket would wait that long for its
ack. :class:`Pacer` lets such a pass run in slices.

Better still, such records should not fall due together. Vehicles that
connect together (a fleet after a restart, or a bench) open their buckets and
are written back in step, and stay in step: every ``bucket_max_age_s`` the
writer would then have ten thousand buckets in one pass. :func:`period_of`
gives each key its own period, a little shorter than the setting's, so that
records due together once drift apart within a few periods.
"""

from __future__ import annotations

import asyncio
import time
import zlib

#: The most a key's period is shorter than the setting's (a fraction of it).
SPREAD = 0.25


def period_of(key: str, period_s: float) -> float:
    """``period_s`` shortened by up to :data:`SPREAD` of it, by a hash of ``key``: the
    same key always gets the same period (never longer than ``period_s``)."""
    return period_s * (1.0 - SPREAD * zlib.crc32(key.encode()) / 2**32)


#: Work between two turns of the event loop (seconds).
SLICE_S = 0.005


class Pacer:
    """Call :meth:`step` after each unit of work: it yields once ``slice_s`` has run."""

    def __init__(self, slice_s: float = SLICE_S) -> None:
        self.slice_s = slice_s
        self._since = time.monotonic()
        self.yields = 0

    async def step(self) -> None:
        now = time.monotonic()
        if now - self._since >= self.slice_s:
            await asyncio.sleep(0)
            self.yields += 1
            self._since = time.monotonic()
