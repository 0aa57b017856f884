"""Domain events from one service to the handlers registered for them.

The composition root registers each handler once, at start. :meth:`MessageBus.emit`
awaits the handlers in the order they were registered (a finish is answered
after the lease and the commands it ends); :meth:`MessageBus.emit_now` is for
code that cannot wait (a sample on the hot path, a presence change): it calls
the handlers and runs what they leave to await as a task. A handler that
fails is logged and counted; the others still run.
"""

from __future__ import annotations

import asyncio
import inspect
import logging
from collections.abc import Awaitable, Callable
from typing import Any, TypeVar

log = logging.getLogger("fleet.messages")

E = TypeVar("E")
Handler = Callable[[Any], Awaitable[None] | None]


class MessageBus:
    def __init__(self, on_failure: Callable[[str], None] | None = None) -> None:
        self._handlers: dict[type, list[Handler]] = {}
        self._tasks: set[asyncio.Task[None]] = set()
        self._on_failure = on_failure

    def register(self, event_type: type[E], handler: Callable[[E], Awaitable[None] | None]) -> None:
        self._handlers.setdefault(event_type, []).append(handler)

    async def emit(self, event: object) -> None:
        for handler in self._handlers.get(type(event), ()):
            try:
                result = handler(event)
                if inspect.isawaitable(result):
                    await result
            except Exception:
                self._failed(event, handler)

    def emit_now(self, event: object) -> None:
        for handler in self._handlers.get(type(event), ()):
            try:
                result = handler(event)
            except Exception:
                self._failed(event, handler)
                continue
            if result is not None and inspect.isawaitable(result):
                task = asyncio.ensure_future(self._finish(result, event, handler))
                self._tasks.add(task)
                task.add_done_callback(self._tasks.discard)

    async def _finish(self, result: Awaitable[None], event: object, handler: Handler) -> None:
        try:
            await result
        except Exception:
            self._failed(event, handler)

    def _failed(self, event: object, handler: Handler) -> None:
        name = type(event).__name__
        log.exception("handler %s of %s failed; the others go on", _name(handler), name)
        if self._on_failure is not None:
            self._on_failure(name)

    async def drain(self) -> None:
        """Wait for the handlers :meth:`emit_now` left running (shutdown, tests)."""
        while self._tasks:
            await asyncio.gather(*list(self._tasks), return_exceptions=True)


def _name(handler: Handler) -> str:
    return getattr(handler, "__qualname__", repr(handler))
