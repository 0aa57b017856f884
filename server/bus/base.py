"""The bus interface: publish on a topic, subscribe a local handler to it.

Every live message of the server (events to operators, commands to
vehicles, units' publishes) goes through a :class:`Bus`, so that a
WebSocket on one replica hears what was published on another. A handler is
a plain callable ``(topic, message) -> None`` run on the event loop: it must
not block (hand the message to a connection's outbox, or
``queue.put_nowait``). A handler that raises is logged and does not stop
the fan-out to the others.

A message is a JSON-able ``dict`` or ``bytes`` (a binary media frame). A
local subscriber gets the publisher's object itself: handlers treat
messages as read-only.

A publish may be *kept*: the bus then holds it as its topic's latest message
(:meth:`Bus.kept`), the state a new subscriber gets first. What is kept is
bounded: a message of at most :data:`KEEP_MAX_BYTES` of JSON, and in each
process at most :data:`KEEP_BUDGET_BYTES` of them (the topics published on
longest ago go first); Redis holds each for :data:`KEEP_TTL_S`.
"""

from __future__ import annotations

import itertools
import logging
from abc import ABC, abstractmethod
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from types import TracebackType
from typing import Any, Self

from fleet_protocol.topics import KEEP_MAX_BYTES, Kept

__all__ = [
    "KEEP_MAX_BYTES",
    "Bus",
    "Handler",
    "Kept",
    "LocalRouter",
    "Message",
    "Subscription",
]

log = logging.getLogger(__name__)

Message = bytes | dict[str, Any]
Handler = Callable[[str, Message], None]

#: What one process keeps in all, in bytes of JSON.
KEEP_BUDGET_BYTES = 32 * 2**20
#: How long Redis keeps a topic's latest message after its publish.
KEEP_TTL_S = 24 * 3600


@dataclass(frozen=True, eq=False)
class Subscription:
    """What :meth:`Bus.subscribe` returns; give it back to :meth:`Bus.unsubscribe`."""

    topic: str
    handler: Handler
    key: int


class LocalRouter:
    """Topic -> handlers of this process, and delivery to them."""

    def __init__(self) -> None:
        self._handlers: dict[str, dict[int, Handler]] = {}
        self._keys = itertools.count()

    def add(self, topic: str, handler: Handler) -> tuple[Subscription, bool]:
        """The new subscription, and whether it is the topic's first one here."""
        handlers = self._handlers.setdefault(topic, {})
        subscription = Subscription(topic, handler, next(self._keys))
        handlers[subscription.key] = handler
        return subscription, len(handlers) == 1

    def remove(self, subscription: Subscription) -> bool:
        """Drop it; whether it was the topic's last one here."""
        handlers = self._handlers.get(subscription.topic)
        if handlers is None or handlers.pop(subscription.key, None) is None:
            return False
        if handlers:
            return False
        del self._handlers[subscription.topic]
        return True

    def topics(self) -> list[str]:
        return list(self._handlers)

    def has(self, topic: str) -> bool:
        return topic in self._handlers

    def deliver(self, topic: str, message: Message) -> int:
        """Call each handler of ``topic``; how many were called."""
        handlers = self._handlers.get(topic)
        if not handlers:
            return 0
        for handler in list(handlers.values()):
            try:
                handler(topic, message)
            except Exception:
                log.exception("bus handler for %s failed", topic)
        return len(handlers)


class Bus(ABC):
    """Publish/subscribe between this process's connections and the other replicas'."""

    #: Whether messages leave this process (``/readyz`` reports ``healthy`` then).
    remote: bool = False

    @property
    def healthy(self) -> bool:
        """Whether messages reach the other replicas (always, for a local bus)."""
        return True

    async def start(self) -> None:  # noqa: B027 - optional hook
        """Connect (a local bus has nothing to do)."""

    async def close(self) -> None:  # noqa: B027 - optional hook
        """Disconnect; no handler is called afterwards."""

    _router: LocalRouter
    _kept: Kept

    def has_local(self, topic: str) -> bool:
        """Whether a connection of this process listens on ``topic``."""
        return self._router.has(topic)

    def publish_here_first(self, topic: str, message: Message) -> Awaitable[None] | None:
        """:meth:`publish`, delivered in this process within the call: what is left to
        await (the other replicas), ``None`` on a bus that does not leave the process."""
        if self.remote:
            return self.publish(topic, message)
        self._router.deliver(topic, message)
        return None

    @abstractmethod
    async def publish(self, topic: str, message: Message) -> None:
        """Deliver to every subscriber of ``topic``, here at once and on the other replicas."""

    def keep(self, topic: str, message: dict[str, Any], text: str) -> Awaitable[None] | None:
        """Hold ``message`` (``text``: its JSON) as the topic's latest, here and for the
        other replicas; what is left to await (Redis), ``None`` when nothing is."""
        self._kept.put(topic, message, len(text))
        return None

    async def kept(self, topic: str) -> dict[str, Any] | None:
        """The topic's latest kept message, published here or on another replica."""
        return self._kept.get(topic)

    @abstractmethod
    async def subscribe(self, topic: str, handler: Handler) -> Subscription:
        """Call ``handler`` for each message on ``topic`` from now on.

        When it returns, messages published anywhere after that reach the
        handler (on a remote bus: once the subscription is confirmed, or
        at once if the remote side is down).
        """

    @abstractmethod
    async def unsubscribe(self, subscription: Subscription) -> None:
        """Stop calling the subscription's handler. Unsubscribing twice is harmless."""

    async def __aenter__(self) -> Self:
        await self.start()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()
