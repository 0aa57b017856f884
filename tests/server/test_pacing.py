"""A long background pass gives the event loop back in slices (server.services.pacing)."""

from __future__ import annotations

import asyncio
import time

from server.services.pacing import Pacer, period_of


async def _pass(pacer: Pacer, units: int, unit_s: float, other: asyncio.Task[None]) -> bool:
    """Busy units of work with ``pacer.step()`` between them; whether ``other`` ran meanwhile."""
    for _ in range(units):
        end = time.monotonic() + unit_s
        while time.monotonic() < end:
            pass
        await pacer.step()
    return other.done()


async def test_a_long_pass_lets_waiting_tasks_run_between_slices() -> None:
    other = asyncio.create_task(asyncio.sleep(0))
    pacer = Pacer(slice_s=0.002)
    assert await _pass(pacer, units=10, unit_s=0.001, other=other)
    assert pacer.yields >= 3


async def test_a_short_pass_keeps_the_loop() -> None:
    other = asyncio.create_task(asyncio.sleep(0))
    pacer = Pacer(slice_s=60)
    assert not await _pass(pacer, units=5, unit_s=0.0005, other=other)
    assert pacer.yields == 0
    await other


def test_each_key_has_its_own_period_never_longer_than_the_setting() -> None:
    periods = [period_of(f"usv-{n:05d}", 10.0) for n in range(2000)]
    assert all(7.5 <= p <= 10.0 for p in periods)
    assert period_of("usv-00042", 10.0) == periods[42]  # the same key, the same period
    # Spread over the whole quarter: records due together once drift apart.
    assert min(periods) < 7.6 and max(periods) > 9.9
    tenths = {int((10.0 - p) / 0.25) for p in periods}
    assert tenths == set(range(10))
