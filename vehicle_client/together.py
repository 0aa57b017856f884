"""Loops that live and die together: the agent's four, and a session's four."""

from __future__ import annotations

import asyncio
from typing import Any

from vehicle_client.errors import FatalError, RetryableError, SessionLost

__all__ = ["run_together"]


def _first_error(errors: list[BaseException]) -> BaseException:
    """The error that decides: a fatal one first, then the rest in order."""
    for kind in (FatalError, SessionLost, RetryableError):
        for e in errors:
            if isinstance(e, kind):
                return e
    return errors[0]


async def run_together(coros: dict[str, Any]) -> None:
    """Run the coroutines until one fails; then stop the others and raise its error.

    Like a TaskGroup, except that a cancellation from outside is never lost:
    Python 3.11's TaskGroup drops it when a child fails at the same moment,
    which left the agent retrying after it was told to stop.
    """
    tasks = [asyncio.create_task(coro, name=name) for name, coro in coros.items()]
    try:
        done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_EXCEPTION)
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
    errors = [t.exception() for t in done if not t.cancelled() and t.exception() is not None]
    if errors:
        raise _first_error([e for e in errors if e is not None])
