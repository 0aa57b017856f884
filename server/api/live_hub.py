"""Live links: this replica's WebSocket connections and the vehicles they serve.

The hub keeps the connections (:class:`~server.api.live_conn.Connection`), each
with its outbox, and hands commands, control and failsafe news to the vehicle
sockets it holds; the topics they subscribe and publish go through its fan-out
(:class:`~server.api.live_fanout.TopicFanout`). Transport only: what to say
comes from the services (commands to hand out, a topic's current state,
the server's own topics in :mod:`server.services.live_topics`).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable
from typing import Any

from fleet_protocol.links import CLOSE_RECONNECT, CLOSE_REPLACED, CLOSE_UNAUTHORIZED
from fleet_protocol.ws import AbortPush, CommandPush, ControlPush, FailsafePush
from server.api.live_conn import Connection
from server.api.live_demand import DemandShare
from server.api.live_fanout import TopicFanout
from server.bus import Bus, Message
from server.domain.access import Principal
from server.domain.events import CommandsReady, FailsafeChanged, TokensRevoked
from server.metrics import Hops
from server.services.commands import CommandService
from server.services.control import ControlService
from server.services.instances import InstanceService, InstanceState
from server.services.live_topics import ServerTopics
from server.settings import Settings

log = logging.getLogger("fleet.live")


class LiveHub(TopicFanout):
    """This replica's sockets and the instances they serve (see the module); their topics
    are the fan-out's."""

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
        super().__init__(bus, topics, hops, instances.clock, settings.ws_max_topics)
        self.instances = instances
        self.commands = commands
        self.control = control
        self.connections: set[Connection] = set()
        self._vehicle_socket: dict[str, Connection] = {}  # instance_id -> its socket here
        self._tasks: set[asyncio.Task[Any]] = set()
        #: What this replica's subscribers want of the gateways on the others, and theirs.
        self.demand = DemandShare(bus, self)

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
        """Every frame on a vehicle's socket counts as contact: for the instances it
        serves, or, on a vehicle's own socket that has not named one yet (opened again
        after a link loss, pinging), for the vehicle's live instance."""
        for instance_id in conn.instances:
            state = self.instances.current_by_id(instance_id)
            if state is not None:
                self.instances.touch(state)
        if not conn.instances and conn.principal.kind == "vehicle":
            own = self.instances.current(conn.principal.name)
            if own is not None and not own.finished:
                self.instances.touch(own)

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
        self._drop_units(conn)
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
            (CLOSE_UNAUTHORIZED, "the token is no longer valid (revoked, or its user disabled)")
            if event.revoked
            else (CLOSE_RECONNECT, "your rights changed: connect again")
        )
        for conn in list(self.connections):
            if conn.principal.token_id in event.token_ids or conn.digest in event.digests:
                self._fire(self.close(conn, code, reason))

    async def stop(self) -> None:
        await self.demand.stop()
        for conn in list(self.connections):
            await self.close(conn, 1001, "the server is shutting down")
        for task in list(self._tasks):
            task.cancel()
