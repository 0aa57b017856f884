"""The gateway's own WebSocket for its local units (``listen`` in gateway.toml).

A unit connects to ``ws://<listen>/?vehicle_id=<id>[&unit=<name>]`` (a
vehicle the gateway's token acts for) and speaks the topic ops of
``/ws/client``: ``register``, ``unregister``, ``subscribe``, ``unsubscribe``,
``publish`` (``id`` for an ack). A unit of a vehicle the gateway's token does
not list is closed with 4403 once the server has said which it lists
(``whoami``, at each connection); what a connection's query may be, and the
refusals of one that is not: :mod:`vehicle_client.gateway.unit_admission`.
Every unit is closed with 4401 once the server refused the gateway's own token
(``token_refused``); what else a unit is refused: ``unit_refusals``.

Each connection is a unit of its own (a :class:`LocalUnit`), with its own
subscriptions, registrations, throttles and queue, and several may act for
one vehicle (a sonar driver, a camera, a mission script). A connection that
names itself (``unit=<name>``, an identifier) is that unit: a new connection
with the same vehicle and name replaces the former one (closed with 4409)
and keeps what it held, as a unit coming back after its connection went
stale; one without a name is a new unit each time. The topic ops go up with
``vehicle_id`` for what they change in what the vehicle's units hold
together (:class:`TopicOps`: a topic sent up once, taken back with its last
unit); ``publish`` goes where ``TopicRouter`` says (the other local units
subscribed, the vehicle's own included; up only on demand). Events from
above go to every unit subscribed, and a vehicle's ``routes`` to each of its
units, as they came.

Media frames (binary: a JSON header line, a newline, the bytes; see
``fleet_protocol.media``) on media topics follow the same rules as a
``publish``: a unit sends only under ``vehicle/<its id>/``; the frame goes to
the local units subscribed to its topic and up only when its topic is in
``forward_up``, through :class:`MediaUplink` (latest wins, paced); frames
from above go to the units subscribed. A frame over ``max_media_bytes`` is
refused with a ``too_large`` error (the socket itself reads up to twice
that; past it, it closes with 1009). What goes to a unit waits in its own
:class:`UnitQueue`, where media is latest-wins per topic too.
"""

from __future__ import annotations

import asyncio
import itertools
import logging

from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.exceptions import ConnectionClosed

from fleet_protocol import ErrorBody
from fleet_protocol.links import (
    CLOSE_FORBIDDEN,
    CLOSE_REPLACED,
    CLOSE_UNAUTHORIZED,
    MAX_BINARY_FRAME_BYTES,
    MAX_TEXT_FRAME_BYTES,
)
from fleet_protocol.media import decode_media_frame
from fleet_protocol.ws import AckPush, EventPush, PublishOp, RoutesPush, SubscribeOp
from fleet_protocol.ws_frames import FrameError, parse_client_op
from vehicle_client.errors import AgentError, FatalError
from vehicle_client.gateway.forwarding import LatestKept, LocalUnit, TopicRouter, read_refusal
from vehicle_client.gateway.registrar import Registrar
from vehicle_client.gateway.topic_ops import TopicOps
from vehicle_client.gateway.unit_admission import Refused, admit, listen_address, not_listed
from vehicle_client.gateway.unit_queue import DEFAULT_UNIT_QUEUE, UnitQueue
from vehicle_client.gateway.unit_refusals import (
    TOKEN_REFUSED,
    dropped,
    media_refusal,
    op_refusal,
)
from vehicle_client.gateway.uplink import (
    DEFAULT_MEDIA_UP_PER_S,
    DEFAULT_PUBLISH_UP_PER_S,
    MediaUplink,
    PublishBudget,
)
from vehicle_client.transport.wire import op_frame_bytes
from vehicle_client.transport.ws import WsLink

log = logging.getLogger(__name__)


class UnitServer:
    def __init__(
        self,
        link: WsLink,
        listen: str,
        *,
        max_media_bytes: int = MAX_BINARY_FRAME_BYTES,
        media_up_per_s: float = DEFAULT_MEDIA_UP_PER_S,
        publish_up_per_s: float = DEFAULT_PUBLISH_UP_PER_S,
        queue_size: int = DEFAULT_UNIT_QUEUE,
    ) -> None:
        self.link = link
        self.publish_budget = PublishBudget(publish_up_per_s)
        self.host, self.port = listen_address(listen)
        self.max_media_bytes = max_media_bytes
        self.queue_size = queue_size
        self.router = TopicRouter()
        self.latest = LatestKept()
        #: The states sent after a unit's subscribe was acked above, held until the unit
        #: has its own ack (the server's order: the ack, then the states).
        self._states_due: dict[LocalUnit, list[tuple[str, str]]] = {}
        self.uplink = MediaUplink(link, media_up_per_s)
        self._queues: dict[LocalUnit, UnitQueue] = {}
        self._unnamed = itertools.count(1)
        self.registrar = Registrar(link, self.router)
        self.topic_ops = TopicOps(link, self.router, self.registrar)
        #: The vehicles the gateway's token acts for, as the server last said (None: not yet).
        self.acts_for: frozenset[str] | None = None
        #: Set once the server refused the gateway's token: how a unit's socket closes.
        self._ending: tuple[int, str] | None = None
        self._server: Server | None = None
        link.on_event = self._from_above
        link.on_media = self._media_from_above
        link.on_routes = self._routes
        link.on_open = self._replay

    async def start(self) -> None:
        try:
            self._server = await serve(
                self._serve,
                self.host,
                self.port,
                compression=None,
                max_size=max(2 * self.max_media_bytes, MAX_TEXT_FRAME_BYTES),
            )
        except OSError as exc:
            raise FatalError(f"cannot listen on {self.host}:{self.port}: {exc}") from exc
        self.port = self._server.sockets[0].getsockname()[1] if self.port == 0 else self.port
        log.info("local units: ws://%s:%d/?vehicle_id=...&unit=...", self.host, self.port)

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
        await self.uplink.aclose()
        log.info("local units: %s", self.describe())

    async def token_refused(self) -> None:
        """The server refused the gateway's own token (revoked, expired): each unit is
        closed with 4401 and why, and any that connects until the gateway stops, so that
        its process knows a restart of the gateway will not bring it back. They used to
        see their sockets close with 1001, as at any restart."""
        self._ending = (CLOSE_UNAUTHORIZED, TOKEN_REFUSED)
        log.warning("local units: closing them all (4401): %s", TOKEN_REFUSED)
        queues = list(self._queues.values())
        await asyncio.gather(*(q.conn.close(*self._ending) for q in queues))

    def describe(self) -> str:
        """The forwarding counters, for the status log."""
        r, up = self.router, self.uplink
        vehicles = len({u.vehicle_id for u in self._queues})
        return (
            f"{len(self._queues)} connected ({vehicles} vehicles);"
            f" publishes {r.sent_up} up, {r.kept_local} kept local;"
            f" media {r.media_up} up ({up.sent} sent, {up.replaced} replaced by newer,"
            f" {up.dropped} dropped), {r.media_kept} kept local;"
            f" {self.publish_budget.refused} publishes refused (over the units' share)"
        )

    # -- one unit -------------------------------------------------------------
    async def _serve(self, conn: ServerConnection) -> None:
        if self._ending is not None:
            await conn.close(*self._ending)
            return
        admitted = admit(conn.request.path if conn.request else "", self.acts_for)
        if isinstance(admitted, Refused):
            if admitted.code == CLOSE_FORBIDDEN:
                log.warning("local unit refused: %s", admitted.reason)
            await conn.close(admitted.code, admitted.reason)
            return
        vehicle_id, name = admitted.vehicle_id, admitted.name
        unit = LocalUnit(vehicle_id, name or f"#{next(self._unnamed)}")
        queue = UnitQueue(conn, self.queue_size)
        former = self._queues.get(unit)
        self._queues[unit] = queue
        if former is not None:
            await former.close()
            await former.conn.close(CLOSE_REPLACED, f"another connection took unit {name}")
        await self.topic_ops.join(unit)
        log.info("local unit %s connected", unit)
        try:
            async for frame in conn:
                if isinstance(frame, str):
                    await self._op(unit, queue, frame)
                else:
                    self._media(unit, queue, frame)
        except ConnectionClosed:
            pass
        finally:
            await queue.close()
            if self._queues.get(unit) is queue:
                del self._queues[unit]
                await self.topic_ops.gone(unit)

    async def _op(self, unit: LocalUnit, queue: UnitQueue, frame: str) -> None:
        if len(frame) > MAX_TEXT_FRAME_BYTES:
            error = ErrorBody(
                code="too_large", message=f"a JSON frame has at most {MAX_TEXT_FRAME_BYTES} bytes"
            )
            queue.refuse(None, error)
            return
        try:
            op = parse_client_op(frame)
        except FrameError as exc:
            queue.put(exc.reply().frame())
            return
        if (refused := op_refusal(unit.vehicle_id, op, self.acts_for)) is not None:
            queue.refuse(op.id, refused)
            return
        if isinstance(op, PublishOp):
            refused = await self._publish(unit, op)
            if refused is not None:
                queue.refuse(op.id, refused)
            elif op.id:
                queue.put(AckPush.success(op.id).frame())
            return
        answer, up = await self.topic_ops.take(unit, op)
        due = self._states_due.pop(unit, [])
        if op.id:
            queue.put(answer.frame())
        elif not answer.ok and answer.error is not None:
            queue.refuse(None, answer.error)  # refused above: as the server says it, unasked
        if isinstance(op, SubscribeOp) and answer.ok:
            for topic, frame in due:
                self._put_event(unit, topic, frame)
            self._states(unit, [t for t in op.topics if t not in up])
            told = {topic for topic, _ in due}
            self._states(unit, [t for t in up if t not in told], below_only=True)

    def _states(self, unit: LocalUnit, topics: list[str], *, below_only: bool = False) -> None:
        """A subscription answered here (its vehicle holds the topics above already, or the
        link is down): each topic's state, as the server gives a new subscriber, from
        the latest message the units here got on it. ``below_only``: a subscription the
        server answered with no state, which it has none to give of a unit's message
        here (it never had it, nobody above asked; or it came from this socket, which
        it does not echo): that latest alone (no ``ts``: a unit's, not from above)."""
        for topic in topics:
            push = self.latest.latest(topic)
            if push is not None and not (below_only and push.ts is not None):
                self._put(unit, push.model_copy(update={"snapshot": True}).frame())

    async def _publish(self, unit: LocalUnit, op: PublishOp) -> ErrorBody | None:
        """To the local units subscribed, and up when someone above asked for it; what to
        answer when it should have gone up and did not (the local units have it all the
        same): the link down, the units' share of the uplink spent, a frame too large
        once it names its vehicle. A topic the unit publishes on unregistered is
        registered above first, so that only what someone there asked for goes up."""
        await self.topic_ops.before_publish(unit, op.topic)
        delivery = self.router.publish(unit, op.topic)
        push = EventPush(topic=op.topic, data=op.data)
        frame = push.model_dump_json()
        self.latest.note(op.topic, push, len(frame))
        for other in delivery.local:
            self._put_event(other, op.topic, frame)
        if not delivery.up:
            return None
        if not self.link.connected:
            message = "the cloud link is down: the local units got it, nobody above did"
            return ErrorBody(code="unavailable", message=message)
        upstream = {
            "op": "publish",
            "vehicle_id": unit.vehicle_id,
            "topic": op.topic,
            "data": op.data,
        }
        if (size := op_frame_bytes(upstream, len(frame))) > MAX_TEXT_FRAME_BYTES:
            message = (
                f"sent up it would take {size} bytes (at most {MAX_TEXT_FRAME_BYTES}): "
                "the local units got it, nobody above did"
            )
            return ErrorBody(code="too_large", message=message)
        if not self.publish_budget.take(asyncio.get_running_loop().time()):
            message = (
                f"the gateway sends up at most {self.publish_budget.per_s:g} publishes a "
                "second for its units, the vehicles' own ops first; send fewer"
            )
            return ErrorBody(code="rate_limited", message=message)
        try:
            await self.link.send(upstream)
        except AgentError as exc:
            return ErrorBody(code="unavailable", message=f"the cloud link is down: {exc}")
        return None

    def _media(self, unit: LocalUnit, queue: UnitQueue, frame: bytes) -> None:
        """A unit's media frame: checked like a publish, then to local units and up on demand."""
        if len(frame) > self.max_media_bytes:
            message = f"a media frame has at most {self.max_media_bytes} bytes, not {len(frame)}"
            queue.refuse(None, ErrorBody(code="too_large", message=message))
            return
        try:
            header, _ = decode_media_frame(frame)
        except FrameError as exc:
            queue.put(exc.reply().frame())
            return
        topic = header.topic
        if (refused := media_refusal(unit.vehicle_id, topic)) is not None:
            queue.refuse(None, refused)
            return
        delivery = self.router.publish(unit, topic, media=True)
        for other in delivery.local:
            self._put_media(other, topic, frame)
        if delivery.up and self.link.connected:
            self.uplink.put(topic, frame)

    # -- from above -------------------------------------------------------------
    def _from_above(self, push: EventPush) -> None:
        frame = push.frame()
        self.latest.note(push.topic, push, len(frame))
        # A state that follows a subscribe's ack is for the units that subscribed (not
        # yet listed here, maybe); one after a reconnection, for every unit subscribed.
        waiting = self.topic_ops.awaiting(push.topic) if push.snapshot else None
        if waiting:
            for unit in waiting:
                self._states_due.setdefault(unit, []).append((push.topic, frame))
            return
        for unit in self.router.from_above(push.topic):
            self._put_event(unit, push.topic, frame)

    def _media_from_above(self, frame: bytes) -> None:
        try:
            header, _ = decode_media_frame(frame)
        except FrameError as exc:
            log.warning("a media frame from the server without a header: %s", exc)
            return
        for unit in self.router.from_above(header.topic, media=True):
            self._put_media(unit, header.topic, frame)

    def _routes(self, push: RoutesPush) -> None:
        vehicle_id = self.router.routes(push.unit, push.forward_up, push.forward_down)
        if vehicle_id is not None:
            self.registrar.shown(vehicle_id, push.produces)
            frame = push.frame()
            for unit in self.router.of_vehicle(vehicle_id):
                self._put(unit, frame)

    async def _replay(self) -> None:
        """After a (re)connection: which vehicles the token acts for, then the units'
        registrations and subscriptions again (each vehicle's once); what the server
        refuses of them is let go of and told."""
        await self._learn_vehicles()
        for vehicle_id, topic, error in await self.topic_ops.replay():
            self._let_go(vehicle_id, topic, dropped(topic, error.code, error.message))

    async def _learn_vehicles(self) -> None:
        """Ask the server whom the token acts for; close the units of other vehicles (their
        ops would be refused above). A server without the op leaves every unit in."""
        try:
            ack = await self.link.call({"op": "whoami"}, check=False)
        except AgentError:
            return
        vehicles = (ack.model_extra or {}).get("vehicles")
        if not ack.ok or not isinstance(vehicles, list):
            return
        self.acts_for = frozenset(v for v in vehicles if isinstance(v, str))
        for unit, queue in list(self._queues.items()):
            if unit.vehicle_id not in self.acts_for:
                log.warning("local unit %s: %s", unit, not_listed(unit.vehicle_id))
                await queue.conn.close(CLOSE_FORBIDDEN, not_listed(unit.vehicle_id))
        # A subscription taken while the link was down, before the vehicles were known.
        for unit, held in list(self.router.units.items()):
            for topic in list(held.consumes):
                if (reason := read_refusal(topic, self.acts_for)) is not None:
                    self._let_go(unit.vehicle_id, topic, dropped(topic, "forbidden", reason))

    def _let_go(self, vehicle_id: str, topic: str, error: ErrorBody) -> None:
        """The units of ``vehicle_id`` subscribed to ``topic`` are no longer, here (it is
        not replayed again), each told with an ``error`` push naming it."""
        for unit in self.router.subscribers(topic):
            if unit.vehicle_id == vehicle_id:
                self.router.unsubscribe(unit, [topic])
                log.warning("local unit %s: %s", unit, error.message)
                if (queue := self._queues.get(unit)) is not None:
                    queue.forget([topic])
                    queue.refuse(None, error)

    def _put(self, unit: LocalUnit, frame: str) -> None:
        queue = self._queues.get(unit)
        if queue is not None:
            queue.put(frame)

    def _put_event(self, unit: LocalUnit, topic: str, frame: str) -> None:
        """An event for a unit, at most one per topic every ``throttle_ms`` it asked."""
        queue = self._queues.get(unit)
        if queue is not None:
            queue.put_event(topic, frame, self.router.throttle_ms(unit, topic))

    def _put_media(self, unit: LocalUnit, topic: str, frame: bytes) -> None:
        queue = self._queues.get(unit)
        if queue is not None:
            queue.put_media(topic, frame)
