"""The in-process bus: one replica, no Redis (``FLEET_REDIS_URL`` unset)."""

from __future__ import annotations

from typing import Any

from server.bus.base import (
    KEEP_BUDGET_BYTES,
    Bus,
    Handler,
    Kept,
    LocalRouter,
    Message,
    Subscription,
)

__all__ = ["LocalBus"]


class LocalBus(Bus):
    def __init__(self) -> None:
        self._router = LocalRouter()
        self._kept: Kept[dict[str, Any]] = Kept(KEEP_BUDGET_BYTES)

    async def publish(self, topic: str, message: Message) -> None:
        self._router.deliver(topic, message)

    async def subscribe(self, topic: str, handler: Handler) -> Subscription:
        subscription, _ = self._router.add(topic, handler)
        return subscription

    async def unsubscribe(self, subscription: Subscription) -> None:
        self._router.remove(subscription)
