"""What each WebSocket op does: parse once, authorize, call the service, ack."""

from __future__ import annotations

import time
from collections.abc import Awaitable, Callable, Coroutine
from typing import Any

from pydantic import BaseModel

from fleet_protocol import ErrorBody, UpdateFbMessageResult
from fleet_protocol.links import CLOSE_TOO_BIG
from fleet_protocol.media import decode_media_frame
from fleet_protocol.topics import is_media_topic
from fleet_protocol.ws import (
    AckPush,
    BatchOp,
    ErrorPush,
    FinishInstanceOp,
    HeartbeatOp,
    PublishOp,
    RegisterOp,
    StartInstanceOp,
    SubscribeOp,
    UnregisterOp,
    UnsubscribeOp,
    UpdateFbMessageOp,
    UpdateParamOp,
    WhoAmIOp,
)
from fleet_protocol.ws_frames import FrameError, PartialBatch, parse_client_op, parse_vehicle_op
from server.api.live_conn import Connection
from server.api.live_hub import LiveHub
from server.domain.topics import UnitRef, check_read, check_write, gateways_named, unit_for
from server.errors import FleetError, Invalid, RateLimited
from server.services.instance_state import InstanceState
from server.services.registry import Services

_INSTANCE_OPS = frozenset({FinishInstanceOp, UpdateParamOp, UpdateFbMessageOp, HeartbeatOp})
#: Topics a connection's write permissions are kept for (a client writing to ever new
#: topics starts over, rather than growing the set without end).
_WRITABLE_KEPT = 1024


class OpRunner:
    """Runs the ops of one connection, in the order they arrive."""

    def __init__(self, services: Services, hub: LiveHub, conn: Connection) -> None:
        self.s = services
        self.hub = hub
        self.conn = conn
        self._allowance = float(services.settings.ws_ops_per_s)
        self._stamp = time.monotonic()
        self._parse = parse_vehicle_op if conn.kind == "vehicle" else parse_client_op
        self._max_text = services.settings.ws_max_text_bytes
        self._own_unit: UnitRef | None = None  # the unit an op naming no vehicle acts as
        #: (vehicle acted for, topic) this connection's principal may write (``check_write``
        #: passed), kept while the principal is the same object: a new one (a token seen
        #: again after its cache entry went) is checked afresh.
        self._writable: set[tuple[str | None, str]] = set()
        self._writer: object = None

    def _rate(self) -> None:
        rate = self.s.settings.ws_ops_per_s
        now = time.monotonic()
        self._allowance = min(rate, self._allowance + (now - self._stamp) * rate)
        self._stamp = now
        if self._allowance < 1:
            raise RateLimited(f"more than {rate:g} ops per second on this connection")
        self._allowance -= 1

    def _reply(self, op_id: str | None, error: ErrorBody, *, critical: bool = False) -> None:
        push = AckPush.failure(op_id, error) if op_id else ErrorPush(error=error)
        self.conn.outbox.put(push.frame(), critical=critical)

    def _refuse(self, op_id: str | None, exc: FleetError, *, critical: bool = False) -> None:
        error = ErrorBody(code=exc.code, message=exc.message, details=exc.details)
        self._reply(op_id, error, critical=critical)

    def text_now(self, frame: str, *, contact: bool = False) -> Coroutine[Any, Any, None] | None:
        """Handle a text frame within this call where nothing has to wait: a refusal, or
        a ``publish`` on a bus that does not leave the process (the hot path). Otherwise
        the coroutine that handles it, not started.

        Every frame counts against the socket's rate, a malformed one too; one over the
        size bound closes the socket (1009). ``contact``: every frame counts as contact
        from the socket's vehicles (an ``update_param`` of one of them, handled here,
        counts itself: one reading of the clock for both)."""
        if len(frame) > self._max_text:
            if contact:
                self.hub.touch(self.conn)
            self.hub.close_soon(
                self.conn, CLOSE_TOO_BIG, f"a JSON frame has at most {self._max_text} bytes"
            )
            return None
        try:
            op = self._parse(frame)
        except FrameError as exc:
            if contact:
                self.hub.touch(self.conn)
            if self._over_rate(None):
                return None
            if isinstance(exc, PartialBatch):
                return self._partial(exc)
            self.conn.outbox.put(exc.reply().frame())
            return None
        kind = type(op)
        instances = self.conn.instances
        own_update = kind is UpdateParamOp and op.instance_id in instances
        over_rate = self._over_rate(op.id)
        # On a vehicle's own socket an update_param that goes on counts the contact itself;
        # on a gateway's, every instance the socket serves counts this frame.
        if contact and (over_rate or not (own_update and len(instances) == 1)):
            self.hub.touch(self.conn)
        if over_rate:
            return None
        if kind is PublishOp and not self.hub.bus.remote:
            self._publish_now(op)
            return None
        if own_update:
            return self._update_param_now(op)
        return self.run(op)

    def _update_param_now(self, op: UpdateParamOp) -> Coroutine[Any, Any, None] | None:
        """:meth:`run` for a vehicle's ``update_param`` on an instance this socket has: done
        within this call when nothing waits (the hot path, once a second per vehicle), else
        the coroutine that does it."""
        try:
            result = self.s.link.update_param_now(self.conn.principal, op, "ws")
        except FleetError as exc:
            self._refuse(op.id, exc)
            self.hub.flush_routes()
            return None
        if result is None:
            return self.run(op)
        if op.id:
            self.conn.outbox.put(AckPush.success_frame(op.id, result))
        self.hub.flush_routes()
        return None

    def _over_rate(self, op_id: str | None) -> bool:
        """Count one frame against the rate; when over it, refuse the frame (True)."""
        try:
            self._rate()
        except FleetError as exc:
            self._reply(op_id, ErrorBody(code=exc.code, message=exc.message))
            return True
        return False

    def binary_now(self, frame: bytes) -> Awaitable[None] | None:
        """A media frame, like :meth:`text_now`: delivered here within this call; what is
        left to await when the bus also takes it to other replicas."""
        limit = self.s.settings.ws_max_binary_bytes
        if len(frame) > limit:
            self.hub.close_soon(
                self.conn, CLOSE_TOO_BIG, f"a binary frame has at most {limit} bytes"
            )
            return None
        try:
            self._rate()
            header, _ = decode_media_frame(frame)
            if not is_media_topic(header.topic):
                message = f"{header.topic} is not a media topic; send JSON on it"
                raise Invalid(message, details=[{"field": "topic", "message": message}])
            check_write(self.conn.principal, header.topic)
        except FrameError as exc:
            self.conn.outbox.put(exc.reply().frame())
            return None
        except FleetError as exc:
            self._refuse(None, exc)
            return None
        return self.hub.publish_media(header.topic, frame)

    async def run(self, op: Any) -> None:
        """Run one op (its frame was counted against the rate: a batch, a gateway's tick,
        counts once)."""
        kind = type(op)  # parsed ops are exactly these classes: no isinstance walk
        if kind is BatchOp:
            await self._run_batch(op)
            return
        taking: InstanceState | None = None
        try:
            taking = await self._taken_up(op)
            result = await self.dispatch(op)
        except FleetError as exc:
            self._refuse(op.id, exc, critical=taking is not None)
            self.hub.flush_routes()
            if taking is not None:
                await self.hub.attach_instance(self.conn, taking)
            return
        if kind is StartInstanceOp:
            taking = self.s.instances.current(op.vehicle_id)
        if op.id:
            # Critical when the socket takes an instance up: then the ack goes before
            # what that sends (control, the queued commands: a ``stop`` is critical too).
            ack = AckPush.success_frame(op.id, result)
            self.conn.outbox.put(ack, critical=taking is not None)
        # After the ack: the pushes the op set off.
        self.hub.flush_routes()
        if taking is not None:
            await self.hub.attach_instance(self.conn, taking)
        elif kind is SubscribeOp:
            await self.hub.start_streams(self.conn, op.topics)

    async def _run_batch(
        self, batch: BatchOp, in_order: list[Any] | None = None, refused: int = 0
    ) -> None:
        """A batch's ops, one after the other (``in_order``, when given: the batch as sent,
        an invalid op's :class:`FrameError` in its place, answered there); its own ``id``
        acked with how many ran (and how many were refused, when some were)."""
        for inner in batch.ops if in_order is None else in_order:
            if type(inner) is FrameError:
                self.conn.outbox.put(inner.reply().frame())
            else:
                await self.run(inner)
        if batch.id:
            result = {"count": len(batch.ops)}
            if refused:
                result["refused"] = refused
            self.conn.outbox.put(AckPush.success(batch.id, result).frame())

    def _partial(self, exc: PartialBatch) -> Coroutine[Any, Any, None] | None:
        """A batch some of whose ops are invalid: the ops answered in the order sent, each
        invalid one refused in its place by its own ``id`` (an ``error`` push for one
        without), the valid ones run. None valid: each refused by its ``id``, then the
        frame refused whole (by the batch's ``id``), as any bad frame."""
        batch = exc.batch
        if not batch.ops:
            for refusal in exc.refused:
                if refusal.op_id is not None:
                    self.conn.outbox.put(refusal.reply().frame())
            self.conn.outbox.put(exc.reply().frame())
            return None
        return self._run_batch(batch, exc.in_order, len(exc.refused))

    def _publish_now(self, op: PublishOp) -> None:
        """:meth:`run` for a ``publish`` on a local bus, where nothing waits."""
        try:
            self._publish_local(op)
        except FleetError as exc:
            self._refuse(op.id, exc)
        else:
            if op.id:
                self.conn.outbox.put(AckPush.success_frame(op.id, None))
        self.hub.flush_routes()

    async def _taken_up(self, op: Any) -> InstanceState | None:
        """The instance an op names that this socket does not serve yet and takes up once
        the op is answered (its ``control`` push and queued commands come after the ack);
        None: none. An instance the caller may not act for is refused here (404)."""
        if type(op) not in _INSTANCE_OPS or op.instance_id in self.conn.instances:
            return None
        state = await self.s.instances.for_vehicle_caller(self.conn.principal, op.instance_id)
        # A vehicle's own new socket takes the instance over (the former is closed,
        # 4409); a gateway's routine op does not take it from the vehicle's own live
        # socket (they took it from each other at every heartbeat): its start does.
        taken = self.conn.principal.kind == "gateway" and self.hub.served_elsewhere(
            state.instance_id, self.conn
        )
        return None if type(op) is FinishInstanceOp or taken else state

    async def dispatch(self, op: Any) -> BaseModel | dict[str, Any] | None:
        handler = _HANDLERS.get(type(op))
        if handler is None:
            raise Invalid(f"op {getattr(op, 'op', '?')} is not handled here")
        return await handler(self, op)

    # ---- one method per op (looked up by the op's type) --------------------------
    async def _start(self, op: StartInstanceOp) -> BaseModel:
        return await self.s.link.start(self.conn.principal, op)

    async def _finish(self, op: FinishInstanceOp) -> BaseModel:
        return await self.s.link.finish(self.conn.principal, op.instance_id)

    async def _heartbeat(self, op: HeartbeatOp) -> BaseModel:
        return await self.s.link.heartbeat(self.conn.principal, op.instance_id)

    async def _update_param(self, op: UpdateParamOp) -> dict[str, int]:
        return await self.s.link.update_param(self.conn.principal, op, "ws")

    async def _update_fb(self, op: UpdateFbMessageOp) -> BaseModel:
        abort = await self.s.link.feedback(self.conn.principal, op)
        return UpdateFbMessageResult(abort=abort)

    async def _register(self, op: RegisterOp) -> dict[str, Any]:
        check_write(self.conn.principal, op.topics, op.vehicle_id)
        self.hub.register(self.conn, self._unit(op.vehicle_id), op.topics)
        return {"topics": op.topics}

    async def _unregister(self, op: UnregisterOp) -> dict[str, Any]:
        self.hub.unregister(self.conn, self._unit(op.vehicle_id), op.topics)
        return {"topics": op.topics}

    async def _subscribe(self, op: SubscribeOp) -> dict[str, Any]:
        principal = self.conn.principal
        named = gateways_named(op.topics)
        gateways = await self.s.auth.gateway_vehicles(named) if named else None
        check_read(principal, op.topics, gateways)
        unit = self._unit(op.vehicle_id)
        self.hub.subscribe(self.conn, unit, op.topics, op.throttle_ms)
        return {"topics": op.topics}

    async def _unsubscribe(self, op: UnsubscribeOp) -> dict[str, Any]:
        unit = self._unit(op.vehicle_id)
        await self.hub.unsubscribe(self.conn, unit, op.topics)
        return {"topics": op.topics}

    async def _whoami(self, op: WhoAmIOp) -> BaseModel:
        return self.s.link.whoami(self.conn.principal)

    def _unit(self, vehicle_id: str | None) -> UnitRef:
        """The unit an op acts as (``unit_for``); the connection's own one kept."""
        if vehicle_id is not None:
            return unit_for(self.conn.principal, vehicle_id)
        if self._own_unit is None:
            self._own_unit = unit_for(self.conn.principal)
        return self._own_unit

    async def _publish(self, op: PublishOp) -> None:
        pending = self._publish_local(op)
        if pending is not None:
            await pending

    def _publish_local(self, op: PublishOp) -> Awaitable[None] | None:
        """Check and publish; what is left to await when the bus leaves the process."""
        principal = self.conn.principal
        unit = self._unit(op.vehicle_id)
        if principal is not self._writer or len(self._writable) >= _WRITABLE_KEPT:
            self._writer, self._writable = principal, set()
        if (op.vehicle_id, op.topic) not in self._writable:
            check_write(principal, op.topic, op.vehicle_id)
            if is_media_topic(op.topic):
                message = f"{op.topic} is a media topic: send binary frames on it"
                raise Invalid(message, details=[{"field": "topic", "message": message}])
            self._writable.add((op.vehicle_id, op.topic))
        return self.hub.publish(self.conn, unit, op.topic, op.data)


#: op type -> its method (one table for every connection).
_HANDLERS: dict[type, Callable[[OpRunner, Any], Awaitable[Any]]] = {
    StartInstanceOp: OpRunner._start,
    FinishInstanceOp: OpRunner._finish,
    HeartbeatOp: OpRunner._heartbeat,
    UpdateParamOp: OpRunner._update_param,
    UpdateFbMessageOp: OpRunner._update_fb,
    RegisterOp: OpRunner._register,
    UnregisterOp: OpRunner._unregister,
    SubscribeOp: OpRunner._subscribe,
    UnsubscribeOp: OpRunner._unsubscribe,
    PublishOp: OpRunner._publish,
    WhoAmIOp: OpRunner._whoami,
}
