"""Demand across replicas: the topics a gateway's units may produce that subscribers on
the other replicas want.

Each replica's routing table holds the units whose sockets it serves, and a
gateway forwards up only what its table's ``forward_up`` says someone outside
the gateway wants. A subscriber on another replica is in that replica's table
alone: without this, a gateway kept to itself what only such a subscriber
wanted. So each replica tells the others, on the bus topic ``_demand``, which
topics under ``vehicle/<id>/`` (those units write, the server's own left out)
its units subscribe to: at once when that set changes, and again every
:data:`EVERY_S` as a sign of life. Each other replica stands in its table as
one unit, ``replica:<id>``, consuming that set; one not heard for
:data:`FORGET_AFTER_S` is taken out. The same code runs on one replica: with
no bus leaving the process, it has no one to tell.
"""

from __future__ import annotations

import secrets
import time
from collections.abc import Callable
from typing import Any

from server.api.live_fanout import TopicFanout
from server.bus import Bus, Message, Subscription
from server.domain.topics import vehicle_written

__all__ = ["DEMAND_TOPIC", "DemandShare"]

DEMAND_TOPIC = "_demand"
#: How often a replica says its demand when it has not changed.
EVERY_S = 2.0
#: A replica not heard for this long is taken out of the others' tables.
FORGET_AFTER_S = 3 * EVERY_S
REPLICA_PREFIX = "replica:"


class DemandShare:
    def __init__(
        self, bus: Bus, fanout: TopicFanout, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.bus = bus
        self.fanout = fanout
        self.clock = clock
        self.replica = secrets.token_hex(4)
        self._said: frozenset[str] | None = None
        self._local: tuple[int, frozenset[str]] = (-1, frozenset())
        self._said_at = 0.0
        self._heard: dict[str, float] = {}  # replica unit -> when last heard
        self._subscription: Subscription | None = None

    async def step(self) -> None:
        """Say this replica's demand if it changed or is due; forget replicas gone quiet."""
        if not self.bus.remote:
            return
        if self._subscription is None:
            self._subscription = await self.bus.subscribe(DEMAND_TOPIC, self._hear)
        now = self.clock()
        mine = self.local()
        if mine != self._said or now - self._said_at >= EVERY_S:
            message = {"replica": self.replica, "topics": sorted(mine)}
            await self.bus.publish(DEMAND_TOPIC, message)
            self._said, self._said_at = mine, now
        for unit, heard in list(self._heard.items()):
            if now - heard > FORGET_AFTER_S:
                del self._heard[unit]
                self.fanout.remote_demand(unit, None)

    async def stop(self) -> None:
        if self._subscription is not None:
            await self.bus.unsubscribe(self._subscription)
            self._subscription = None

    def local(self) -> frozenset[str]:
        """The shared topics this replica's own units subscribe to (worked out again only
        when the routing table changed)."""
        version, topics = self._local
        if version == self.fanout.routing.version:
            return topics
        routing = self.fanout.routing
        topics = frozenset(
            topic
            for topic in routing.consumed()
            if vehicle_written(topic)
            and any(not u.startswith(REPLICA_PREFIX) for u in routing.subscribers(topic))
        )
        self._local = (self.fanout.routing.version, topics)
        return topics

    def _hear(self, _topic: str, message: Message) -> None:
        said: Any = message if isinstance(message, dict) else {}
        replica, topics = said.get("replica"), said.get("topics")
        if not isinstance(replica, str) or replica == self.replica or not isinstance(topics, list):
            return
        unit = REPLICA_PREFIX + replica
        self._heard[unit] = self.clock()
        wanted = {t for t in topics if isinstance(t, str) and vehicle_written(t)}
        self.fanout.remote_demand(unit, wanted)
