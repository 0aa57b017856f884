"""Live links: this replica's WebSocket connections, their topics and units.

The hub keeps the connections, each with its outbox, and the routing table
of the multilayer interface; it subscribes each socket's topics on the bus
(so that a socket on one replica hears what was published on another) and
hands commands to the vehicle sockets it holds. Transport only: what to say
comes from the services (commands to hand out, a topic's current state,
the server's own topics in :mod:`server.services.live_topics`).
"""

from __future__ import annotations

import asyncio
import calendar
import functools
import logging
import secrets
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

from fleet_protocol import format_ts, utcnow
from fleet_protocol.common import now_ts, parse_ts
from fleet_protocol.links import CLOSE_RECONNECT, CLOSE_REPLACED, CLOSE_UNAUTHORIZED
from fleet_protocol.topics import is_media_topic
from fleet_protocol.ws import (
    AbortPush,
    CommandPush,
    ControlPush,
    EventPush,
    FailsafePush,
    RoutesPush,
)
from server.api.outbox import Outbox
from server.bus import Bus, Message, Subscription
from server.bus.wire import dumps
from server.domain.access import Principal
from server.domain.events import CommandsReady, FailsafeChanged, TokensRevoked
from server.domain.routing import RoutingTable
from server.domain.topics import UnitRef
from server.metrics import Hops
from server.services.commands import CommandService
from server.services.control import ControlService
from server.services.instances import InstanceService, InstanceState
from server.services.live_topics import ServerTopics
from server.settings import Settings

log = logging.getLogger("fleet.live")


@dataclass(eq=False)
class Connection:
    """One WebSocket: who it is, its outbox, its subscriptions and units."""

    principal: Principal
    outbox: Outbox
    close: Callable[[int, str], Awaitable[None]]
    kind: str  # "vehicle" (vehicle and gateway tokens) or "client"
    digest: str = ""  # the token's digest (its revocation closes the socket)
    id: str = field(default_factory=lambda: secrets.token_hex(8))
    subs: dict[tuple[str, str], Subscription] = field(default_factory=dict)
    throttle: dict[str, int] = field(default_factory=dict)
    #: topic -> the units of this connection subscribed to it (a gateway serves several)
    topic_units: dict[str, set[str]] = field(default_factory=dict)
    units: set[str] = field(default_factory=set)
    instances: set[str] = field(default_factory=set)  # instances this socket serves
    buffering: dict[str, list[Message]] = field(default_factory=dict)
    closed: bool = False


class LiveHub:
    def __init__(
        self,
        settings: Settings,
        bus: Bus,
        instances: InstanceService,
        commands: CommandService,
        control: ControlService,
        topics: ServerTopics,
        hops: Hops,
    ) -> None:
        self.bus = bus
        self.hops = hops
        clock = instances.clock
        #: The server's clock in seconds since the epoch (the events' ``ts`` are on it).
        self._wall: Callable[[], float] = (
            time.time if clock is utcnow else lambda: clock().timestamp()
        )
        self._stamped: dict[str, Any] | None = None
        self._stamp: float | None = None
        self.instances = instances
        self.commands = commands
        self.control = control
        self.routing = RoutingTable(settings.ws_max_topics)
        self.connections: set[Connection] = set()
        self._vehicle_socket: dict[str, Connection] = {}  # instance_id -> its socket here
        self._unit_conn: dict[str, Connection] = {}
        self._tasks: set[asyncio.Task[Any]] = set()
        self._last_message: dict[str, Any] | None = None
        self._routes_due: set[str] = set()
        self._last_frame = ""
        #: The topics the server writes: their current state for a new subscriber.
        self.topics = topics

    def _fire(self, coro: Awaitable[Any]) -> None:
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    # ---- commands to vehicle sockets ------------------------------------------
    def on_commands_ready(self, event: CommandsReady) -> None:
        self._on_ready(event.instance_id)

    def _on_ready(self, instance_id: str) -> None:
        if instance_id in self._vehicle_socket:
            self._fire(self.deliver_commands(instance_id))
        else:  # the vehicle's socket may be on another replica
            self._fire(self.bus.publish(f"_ready/{instance_id}", {"instance_id": instance_id}))

    async def deliver_commands(self, instance_id: str) -> None:
        conn = self._vehicle_socket.get(instance_id)
        if conn is None or conn.closed:
            return
        state = self.instances.current_by_id(instance_id)
        if state is None:
            return
        for cmd in await self.commands.take(state):
            push = CommandPush.model_validate(cmd.wire())
            conn.outbox.put(push.frame(), critical=push.critical)
        if aborts := self.commands.take_aborts(instance_id):
            told = AbortPush(instance_id=instance_id, command_ids=aborts)
            conn.outbox.put(told.frame(), critical=told.critical)

    async def attach_instance(self, conn: Connection, state: InstanceState) -> None:
        """This socket now serves the instance: commands and control go to it."""
        former = self._vehicle_socket.get(state.instance_id)
        self._vehicle_socket[state.instance_id] = conn
        conn.instances.add(state.instance_id)
        if former is not None and former is not conn:
            former.instances.discard(state.instance_id)
            if former.principal.kind == "vehicle":
                await self.close(former, CLOSE_REPLACED, "another connection took this vehicle")
        if ("_ready", state.instance_id) not in conn.subs:
            conn.subs[("_ready", state.instance_id)] = await self.bus.subscribe(
                f"_ready/{state.instance_id}", lambda _t, m: self._on_ready_remote(conn, state, m)
            )
            topic = f"vehicle/{state.vehicle_id}/control"
            conn.subs[("_control", topic)] = await self.bus.subscribe(
                topic, lambda _t, m: self._control_push(conn, m)
            )
            conn.subs[("_failsafe", state.instance_id)] = await self.bus.subscribe(
                f"_failsafe/{state.vehicle_id}",
                lambda _t, m: self._failsafe_push(conn, state.instance_id, m),
            )
        control = self.control.lease_info(state.instance_id)
        conn.outbox.put(ControlPush(instance_id=state.instance_id, control=control).frame())
        await self.deliver_commands(state.instance_id)

    def served_elsewhere(self, instance_id: str, conn: Connection) -> bool:
        """Whether another live socket here serves the instance."""
        other = self._vehicle_socket.get(instance_id)
        return other is not None and other is not conn and not other.closed

    def calls_over_http(
        self, principal: Principal, instance_id: str, *, everywhere: bool = False
    ) -> None:
        """The vehicle calls over HTTP now (an agent that fell back to the long poll): a
        socket that still serves the instance (half-open: nobody reads it, and every
        command and redelivery would go into it) stops serving it. A vehicle's socket is
        closed (4409), a gateway's keeps its other vehicles. ``everywhere``: on the other
        replicas too (a ``start_instance``; a long poll looks on this replica only). Only
        for a caller that acts for the instance's vehicle (else :class:`NotFound`, as the
        call itself answers)."""
        if instance_id in self._vehicle_socket:
            self.instances.kept_for_vehicle_caller(principal, instance_id)
        self._detach(instance_id)
        if everywhere:  # told on the topic the socket's replica hears for the instance
            message = {"instance_id": instance_id, "http": True}
            self._fire(self.bus.publish(f"_ready/{instance_id}", message))

    def _detach(self, instance_id: str) -> None:
        conn = self._vehicle_socket.pop(instance_id, None)
        if conn is not None:
            conn.instances.discard(instance_id)
            if conn.principal.kind == "vehicle":
                self.close_soon(conn, CLOSE_REPLACED, "the vehicle calls over HTTP now")

    def _on_ready_remote(self, conn: Connection, state: InstanceState, message: Message) -> None:
        """News for the instance from some replica: commands to hand out; or the vehicle
        started over HTTP (``http``), and this socket, if it still serves the instance, no
        longer does."""
        if isinstance(message, dict) and message.get("http"):
            if self._vehicle_socket.get(state.instance_id) is conn:
                self._detach(state.instance_id)
            return
        self._fire(self.deliver_commands(state.instance_id))

    @staticmethod
    def _control_push(conn: Connection, message: Message) -> None:
        if isinstance(message, dict):
            data = message.get("data") or {}
            push = ControlPush(instance_id=data.get("instance_id", ""), control=data.get("control"))
            conn.outbox.put(push.frame())

    def on_failsafe_changed(self, event: FailsafeChanged) -> None:
        """A vehicle's policy changed: to its socket, on whichever replica holds it."""
        self._fire(self.bus.publish(f"_failsafe/{event.vehicle_id}", {"policy": event.policy}))

    @staticmethod
    def _failsafe_push(conn: Connection, instance_id: str, message: Message) -> None:
        if isinstance(message, dict) and instance_id in conn.instances:
            push = FailsafePush(instance_id=instance_id, failsafe=message["policy"])
            conn.outbox.put(push.frame(), critical=True)

    def touch(self, conn: Connection) -> None:
        """Every frame on a vehicle's socket counts as contact."""
        for instance_id in conn.instances:
            state = self.instances.current_by_id(instance_id)
            if state is not None:
                self.instances.touch(state)

    # ---- subscriptions ------------------------------------------------------------
    def subscribe(
        self, conn: Connection, unit: UnitRef, topics: list[str], throttle_ms: int
    ) -> None:
        """Enter the subscription in the routing table (may refuse: too many topics)."""
        self._add_unit(conn, unit)
        changed = self.routing.subscribe(unit.id, topics)
        for topic in topics:
            conn.throttle[topic] = throttle_ms
            conn.topic_units.setdefault(topic, set()).add(unit.id)
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
            try:
                snapshot = await self.topics.snapshot(conn.principal, topic)
            finally:
                held = conn.buffering.pop(topic, [])
            if snapshot is not None:
                frame = EventPush(topic=topic, data=snapshot, snapshot=True).frame()
                conn.outbox.put(frame, topic=topic)
            for message in held:
                self._deliver(conn, topic, message)

    async def unsubscribe(self, conn: Connection, unit: UnitRef, topics: list[str]) -> None:
        if unit.id in self.routing:
            self._push_routes(self.routing.unsubscribe(unit.id, topics))
        for topic in topics:
            units = conn.topic_units.get(topic, set())
            units.discard(unit.id)
            if units:
                continue  # another unit behind this gateway still wants it
            conn.topic_units.pop(topic, None)
            sub = conn.subs.pop(("sub", topic), None)
            if sub is not None:
                await self.bus.unsubscribe(sub)
            conn.throttle.pop(topic, None)
            conn.outbox.forget(topic)

    def register(self, conn: Connection, unit: UnitRef, topics: list[str]) -> None:
        self._add_unit(conn, unit)
        self._push_routes(self.routing.register(unit.id, topics))

    def unregister(self, conn: Connection, unit: UnitRef, topics: list[str]) -> None:
        self._add_unit(conn, unit)
        self._push_routes(self.routing.unregister(unit.id, topics))

    def publish(
        self, conn: Connection, unit: UnitRef, topic: str, data: Any
    ) -> Awaitable[None] | None:
        """A unit's message to the topic's subscribers (not back to its own connection).

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
            "ts": now_ts() if self.instances.clock is utcnow else format_ts(self.instances.clock()),
        }
        return self.bus.publish_here_first(topic, message)  # no coroutine on a local bus

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
    def _add_unit(self, conn: Connection, unit: UnitRef) -> None:
        if unit.parent is not None and unit.parent not in self.routing:
            self.routing.add_unit(unit.parent, "gateway")
            self._unit_conn[unit.parent] = conn
            conn.units.add(unit.parent)
        if unit.id not in self.routing:
            self.routing.add_unit(unit.id, unit.kind, unit.parent)
        self._unit_conn[unit.id] = conn
        conn.units.add(unit.id)

    def _push_routes(self, changed: frozenset[str]) -> None:
        """Note whose part of the table changed; :meth:`flush_routes` tells them."""
        self._routes_due |= changed

    def flush_routes(self) -> None:
        """Send ``routes`` to each unit whose part changed (after the op's ack).

        A gateway's own part goes before its units': the gateway relays a unit's
        part to it, and the unit may publish at once on what it learned, so the
        gateway must know by then what to forward up.
        """
        if not self._routes_due:
            return
        due, self._routes_due = self._routes_due, set()
        for unit_id in sorted(due, key=lambda u: (not u.startswith("gateway:"), u)):
            conn = self._unit_conn.get(unit_id)
            if conn is not None and not conn.closed and unit_id in self.routing:
                view = self.routing.view(unit_id)
                conn.outbox.put(RoutesPush(**view.as_dict()).frame())

    # ---- connections --------------------------------------------------------------
    def add(self, conn: Connection) -> None:
        self.connections.add(conn)
        conn.outbox.start()

    def close_soon(self, conn: Connection, code: int, reason: str) -> None:
        """:meth:`close` from code that cannot wait (an outbox giving up on its reader)."""
        self._fire(self.close(conn, code, reason))

    async def close(self, conn: Connection, code: int, reason: str) -> None:
        if conn.closed:
            return
        conn.closed = True
        try:
            await conn.outbox.close()
        finally:
            await conn.close(code, reason)

    async def drop(self, conn: Connection) -> None:
        """Forget a connection that ended: its subscriptions, units and instances."""
        conn.closed = True
        self.connections.discard(conn)
        for sub in conn.subs.values():
            await self.bus.unsubscribe(sub)
        conn.subs.clear()
        changed: set[str] = set()
        for unit_id in sorted(conn.units, key=lambda u: u.startswith("gateway:")):
            if self._unit_conn.get(unit_id) is conn and unit_id in self.routing:
                changed |= self.routing.remove_unit(unit_id)
                del self._unit_conn[unit_id]
        self._push_routes(frozenset(changed - conn.units))
        self.flush_routes()
        for instance_id in conn.instances:
            if self._vehicle_socket.get(instance_id) is conn:
                del self._vehicle_socket[instance_id]
        await conn.outbox.close()

    def on_tokens_revoked(self, event: TokensRevoked) -> None:
        """Close the sockets this replica holds for tokens revoked here or elsewhere: 4401;
        for tokens whose user's rights changed, a code to reconnect with (the socket's
        subscriptions were checked against the former rights)."""
        if not (event.token_ids or event.digests):
            return
        code, reason = (
            (CLOSE_UNAUTHORIZED, "the token was revoked")
            if event.revoked
            else (CLOSE_RECONNECT, "your rights changed: connect again")
        )
        for conn in list(self.connections):
            if conn.principal.token_id in event.token_ids or conn.digest in event.digests:
                self._fire(self.close(conn, code, reason))

    async def stop(self) -> None:
        for conn in list(self.connections):
            await self.close(conn, 1001, "the server is shutting down")
        for task in list(self._tasks):
            task.cancel()


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
