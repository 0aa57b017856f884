"""Long background passes give the event loop back every few milliseconds.

A pass that writes thousands of records (telemetry buckets aging out
together, contact written back for every vehicle) would otherwise hold the
loop for its whole length, and every socket would wait that long for its
ack. :class:`Pacer` lets such a pass run in slices.
"""

from __future__ import annotations

import asyncio
import time

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
