"""Topic fan-out on this replica: the routing table of the multilayer interface, each
socket's topics subscribed on the bus (so that a socket on one replica hears what was
published on another), and a bus message delivered to the outboxes of the sockets that
subscribed to it, encoded once however many they are. A base of
:class:`~server.api.live_hub.LiveHub`, which keeps the sockets themselves.
"""

from __future__ import annotations

import calendar
import functools
import time
from collections.abc import Awaitable, Callable
from typing import Any

from fleet_protocol import format_ts, utcnow
from fleet_protocol.common import now_ts, parse_ts
from fleet_protocol.topics import is_media_topic
from fleet_protocol.ws import EventPush, RoutesPush
from server.api.live_conn import Connection
from server.bus import Bus, Message
from server.bus.wire import dumps
from server.domain.access import Principal
from server.domain.clock import Clock
from server.domain.routing import RoutingTable
from server.domain.topics import UnitRef
from server.metrics import Hops
from server.services.live_topics import ServerTopics


class TopicFanout:
    """The routing table and the topic subscriptions of this replica's sockets, and the
    delivery of each bus message to them (see the module)."""

    def __init__(
        self, bus: Bus, topics: ServerTopics, hops: Hops, clock: Clock, max_topics: int
    ) -> None:
        self.bus = bus
        self.hops = hops
        self._clock = clock
        #: The server's clock in seconds since the epoch (the events' ``ts`` are on it).
        self._wall: Callable[[], float] = (
            time.time if clock is utcnow else lambda: clock().timestamp()
        )
        self._stamped: dict[str, Any] | None = None
        self._stamp: float | None = None
        self.routing = RoutingTable(max_topics)
        #: Each unit's connections (a user's console and fleetctl, a gateway's old socket
        #: and its new one): the unit's part of the table is what any of them holds.
        self._unit_conns: dict[str, list[Connection]] = {}
        self._last_message: dict[str, Any] | None = None
        self._routes_due: set[str] = set()
        #: (socket, unit) a socket joined a unit the table had: told the unit's part too.
        self._joined: list[tuple[Connection, str]] = []
        self._last_frame = ""
        #: The topics the server writes: their current state for a new subscriber.
        self.topics = topics

    # ---- subscriptions ------------------------------------------------------------
    def subscribe(
        self, conn: Connection, unit: UnitRef, topics: list[str], throttle_ms: int
    ) -> None:
        """Enter the subscription in the routing table (may refuse: too many topics)."""
        self._add_unit(conn, unit)
        changed = self.routing.subscribe(unit.id, topics)
        for topic in topics:
            units = conn.topic_units.setdefault(topic, {})
            units[unit.id] = throttle_ms
            conn.throttle[topic] = min(units.values())
        self._push_routes(changed)

    async def start_streams(self, conn: Connection, topics: list[str]) -> None:
        """After the subscribe's ack: each topic's snapshot, then its changes, no gap.

        Messages that arrive while the snapshot is read are held back and
        sent after it.
        """
        for topic in topics:
            if ("sub", topic) in conn.subs or topic not in conn.topic_units:
                continue
            conn.buffering[topic] = []
            conn.subs[("sub", topic)] = await self.bus.subscribe(
                topic, functools.partial(self._deliver, conn)
            )
            kept: dict[str, Any] | None = None
            try:
                snapshot = await self.topics.snapshot(conn.principal, topic)
                if snapshot is None:
                    kept = await self.bus.kept(topic)
            finally:
                held = conn.buffering.pop(topic, [])
            if snapshot is not None:
                frame = EventPush(topic=topic, data=snapshot, snapshot=True).frame()
                conn.outbox.put(frame, topic=topic)
            elif kept is not None and kept.get("origin") != conn.id:
                shown = {k: v for k, v in kept.items() if k != "origin"}
                conn.outbox.put(dumps({**shown, "snapshot": True}), topic=topic)
            for message in held:
                if message != kept:  # the kept one, published while it was read: sent
                    self._deliver(conn, topic, message)

    async def unsubscribe(self, conn: Connection, unit: UnitRef, topics: list[str]) -> None:
        """The unit no longer wants ``topics`` on this connection (its other connections
        keep what they subscribed)."""
        if unit.id in self.routing:
            gone = [t for t in topics if not self._elsewhere(conn, unit.id, t, produced=False)]
            self._push_routes(self.routing.unsubscribe(unit.id, gone))
        for topic in topics:
            units = conn.topic_units.get(topic, {})
            units.pop(unit.id, None)
            if units:  # another unit behind this gateway still wants it
                conn.throttle[topic] = min(units.values())
                continue
            conn.topic_units.pop(topic, None)
            sub = conn.subs.pop(("sub", topic), None)
            if sub is not None:
                await self.bus.unsubscribe(sub)
            conn.throttle.pop(topic, None)
            conn.outbox.forget(topic)

    def register(self, conn: Connection, unit: UnitRef, topics: list[str]) -> None:
        self._add_unit(conn, unit)
        self._push_routes(self.routing.register(unit.id, topics))
        conn.produces.setdefault(unit.id, set()).update(topics)

    def unregister(self, conn: Connection, unit: UnitRef, topics: list[str]) -> None:
        self._add_unit(conn, unit)
        conn.produces.get(unit.id, set()).difference_update(topics)
        gone = [t for t in topics if not self._elsewhere(conn, unit.id, t, produced=True)]
        self._push_routes(self.routing.unregister(unit.id, gone))

    def _elsewhere(self, conn: Connection, unit_id: str, topic: str, *, produced: bool) -> bool:
        """Whether another connection of the unit still registers (``produced``) or
        subscribes to the topic for it."""
        return any(
            topic in other.produces.get(unit_id, ())
            if produced
            else unit_id in other.topic_units.get(topic, ())
            for other in self._unit_conns.get(unit_id, ())
            if other is not conn
        )

    def publish(
        self, conn: Connection, unit: UnitRef, topic: str, data: Any
    ) -> Awaitable[None] | None:
        """A unit's message to the topic's subscribers (not back to its own connection),
        kept as the topic's latest: the state a new subscriber gets first.

        Delivered here at once; on a bus that leaves the process, the rest (the
        other replicas) is the awaitable returned.
        """
        self._add_unit(conn, unit)
        message = {
            "op": "event",
            "topic": topic,
            "data": data,
            "source": unit.id,
            "origin": conn.id,
            "ts": now_ts() if self._clock is utcnow else format_ts(self._clock()),
        }
        keeping = self.bus.keep(topic, message, self._encode(message))
        if keeping is not None:
            return self._kept_then_published(keeping, topic, message)
        return self.bus.publish_here_first(topic, message)  # no coroutine on a local bus

    async def _kept_then_published(
        self, keeping: Awaitable[None], topic: str, message: dict[str, Any]
    ) -> None:
        """Kept for the other replicas before it is published to them: one that subscribes
        and then reads the kept message cannot miss it."""
        await keeping
        await self.bus.publish(topic, message)

    def publish_media(self, topic: str, frame: bytes) -> Awaitable[None] | None:
        """A binary media frame to the topic's subscribers, as :meth:`publish`."""
        return self.bus.publish_here_first(topic, frame)

    def _deliver(self, conn: Connection, topic: str, message: Message) -> None:
        buffer = conn.buffering.get(topic)
        if buffer is not None:
            buffer.append(message)
            return
        throttle = conn.throttle.get(topic, 0)
        if isinstance(message, bytes):
            conn.outbox.put(message, topic=topic, latest_wins=True, throttle_ms=throttle)
            return
        if message.get("origin") == conn.id:
            return  # the publisher's own connection (a gateway delivers to its units itself)
        if topic == "fleet":
            filtered = self._visible_fleet(conn.principal, message)
            if filtered is None:
                return
            frame = dumps(filtered)
        else:
            frame = self._encode(message)
        conn.outbox.put(
            frame,
            topic=topic,
            latest_wins=is_media_topic(topic),
            throttle_ms=throttle,
            stamp=self._published(message) if conn.kind == "client" else None,
        )

    def _published(self, message: dict[str, Any]) -> float | None:
        """When the message was published (its ``ts``, seconds since the epoch), read once
        per message however many operators it goes to."""
        if self._stamped is not message:
            self._stamped = message
            self._stamp = _epoch(message.get("ts"))
        return self._stamp

    def operator_written(self, stamp: float) -> None:
        """An event published at ``stamp`` was written on an operator's socket."""
        self.hops.server_to_operator(self._wall() - stamp)

    def _encode(self, message: dict[str, Any]) -> str:
        """One JSON encoding per message, however many local subscribers it has (without
        ``origin``: the publisher's connection, this server's own routing)."""
        if self._last_message is not message:
            self._last_message = message
            shown = {k: v for k, v in message.items() if k != "origin"}
            self._last_frame = dumps(shown)
        return self._last_frame

    @staticmethod
    def _visible_fleet(principal: Principal, message: dict[str, Any]) -> dict[str, Any] | None:
        vehicles = [v for v in message["data"]["vehicles"] if principal.can_see(v["vehicle_id"])]
        if not vehicles:
            return None
        return {**message, "data": {"vehicles": vehicles}}

    # ---- routing table ------------------------------------------------------------
    def remote_demand(self, unit_id: str, topics: set[str] | None) -> None:
        """Another replica's subscribers (one ``replica:<id>`` unit) want ``topics`` now;
        None: that replica is gone (:mod:`server.api.live_demand`)."""
        if topics is None:
            if unit_id in self.routing:
                self._push_routes(self.routing.remove_unit(unit_id))
        else:
            if unit_id not in self.routing:
                self.routing.add_unit(unit_id, "operator", bounded=False)
            gone = self.routing.consumes_of(unit_id) - topics
            self._push_routes(self.routing.unsubscribe(unit_id, gone))
            self._push_routes(self.routing.subscribe(unit_id, topics))
        self.flush_routes()

    def _add_unit(self, conn: Connection, unit: UnitRef) -> None:
        if unit.parent is not None and unit.parent not in self.routing:
            self.routing.add_unit(unit.parent, "gateway")
            self._held_by(conn, unit.parent)
        if unit.id not in self.routing:
            self.routing.add_unit(unit.id, unit.kind, unit.parent)
        self._held_by(conn, unit.id)

    def _held_by(self, conn: Connection, unit_id: str) -> None:
        if unit_id in conn.units:
            return
        conn.units.add(unit_id)
        conns = self._unit_conns.setdefault(unit_id, [])
        if conns:  # a unit in the table already: this socket is told its part as it joins
            self._joined.append((conn, unit_id))
        conns.append(conn)

    def _push_routes(self, changed: frozenset[str]) -> None:
        """Note whose part of the table changed; :meth:`flush_routes` tells them."""
        self._routes_due |= changed

    def flush_routes(self) -> None:
        """Send ``routes`` to each unit whose part changed (after the op's ack).

        A gateway's own part goes before its units': the gateway relays a unit's
        part to it, and the unit may publish at once on what it learned, so the
        gateway must know by then what to forward up.
        """
        if not self._routes_due and not self._joined:
            return
        due, self._routes_due = self._routes_due, set()
        joined, self._joined = self._joined, []
        for unit_id in sorted(due, key=lambda u: (not u.startswith("gateway:"), u)):
            if unit_id not in self.routing:
                continue
            frame = RoutesPush(**self.routing.view(unit_id).as_dict()).frame()
            for conn in self._unit_conns.get(unit_id, ()):
                if not conn.closed:
                    conn.outbox.put(frame)
        for conn, unit_id in joined:  # a unit's new socket whose part did not change
            if unit_id not in due and unit_id in self.routing and not conn.closed:
                conn.outbox.put(RoutesPush(**self.routing.view(unit_id).as_dict()).frame())

    def _drop_units(self, conn: Connection) -> None:
        """Take what the ended connection held out of the table: a unit it alone held,
        whole; of a unit another connection holds too, the topics no other one holds.
        Tell the others whose part changed."""
        changed: set[str] = set()
        removed: set[str] = set()
        for unit_id in sorted(conn.units, key=lambda u: u.startswith("gateway:")):
            conns = self._unit_conns.get(unit_id, [])
            if conn in conns:
                conns.remove(conn)
            if not conns:
                self._unit_conns.pop(unit_id, None)
                removed.add(unit_id)
            if unit_id not in self.routing:
                continue
            if not conns:
                changed |= self.routing.remove_unit(unit_id)
                continue
            wanted = [t for t, units in conn.topic_units.items() if unit_id in units]
            made = conn.produces.get(unit_id, ())
            changed |= self.routing.unsubscribe(
                unit_id,
                [t for t in wanted if not self._elsewhere(conn, unit_id, t, produced=False)],
            )
            changed |= self.routing.unregister(
                unit_id, [t for t in made if not self._elsewhere(conn, unit_id, t, produced=True)]
            )
        self._push_routes(frozenset(changed - removed))
        self.flush_routes()


_second: tuple[str, int] = ("", 0)


def _epoch(ts: Any) -> float | None:
    """``format_ts``'s text (``2026-01-01T00:00:00.123Z``) as seconds since the epoch, the
    part up to the second read once per second; another ISO 8601 text the slow way;
    None for what is not a time."""
    global _second
    if not isinstance(ts, str):
        return None
    try:
        if len(ts) == 24 and ts[19] == "." and ts[23] == "Z":
            prefix, whole = _second
            if ts[:19] != prefix:
                whole = calendar.timegm(time.strptime(ts[:19], "%Y-%m-%dT%H:%M:%S"))
                _second = (ts[:19], whole)
            return whole + int(ts[20:23]) / 1000
        return parse_ts(ts).timestamp()
    except (ValueError, OverflowError):
        return None
