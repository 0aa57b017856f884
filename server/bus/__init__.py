"""Topic routing between connections: in process, or across replicas through Redis.

Build the bus in the app's lifespan with :func:`make_bus` and ``await
bus.start()`` / ``await bus.close()`` (or ``async with``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from server.bus.base import Bus, Handler, LocalRouter, Message, Subscription
from server.bus.local import LocalBus

if TYPE_CHECKING:
    from server.settings import Settings

__all__ = ["Bus", "Handler", "LocalBus", "LocalRouter", "Message", "Subscription", "make_bus"]


def make_bus(settings: Settings) -> Bus:
    """A :class:`~server.bus.redis_bus.RedisBus` when ``FLEET_REDIS_URL`` is set, else local."""
    if settings.redis_url is None:
        return LocalBus()
    from server.bus.redis_bus import RedisBus

    return RedisBus(settings.redis_url.get_secret_value())
