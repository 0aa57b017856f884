"""The gateway's own WebSocket for its local units (``listen`` in gateway.toml).

A unit connects to ``ws://<listen>/?vehicle_id=<id>`` (a vehicle the
gateway's token acts for) and speaks the topic ops of ``/ws/client``:
``register``, ``subscribe``, ``unsubscribe``, ``publish`` (``id`` for an
ack). The gateway repeats ``register``/``subscribe``/``unsubscribe``
upstream with ``vehicle_id`` and relays the server's ack; ``publish`` goes
where ``TopicRouter`` says (local subscribers, up only on demand). Events
from above and each unit's ``routes`` are passed down as they came. A second
connection for the same vehicle replaces the first (closed with 4409).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
from typing import Any
from urllib.parse import parse_qs, urlsplit

from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.exceptions import ConnectionClosed

from fleet_protocol import ErrorBody
from fleet_protocol.common import ID_PATTERN
from fleet_protocol.ws import (
    AckPush,
    EventPush,
    FrameError,
    PublishOp,
    RegisterOp,
    RoutesPush,
    SubscribeOp,
    UnsubscribeOp,
    parse_client_op,
)
from vehicle_client.errors import AgentError, FatalError
from vehicle_client.gateway.forwarding import TopicRouter, write_refusal
from vehicle_client.transport.ws import WsLink

log = logging.getLogger(__name__)

CLOSE_BAD_REQUEST = 4400
CLOSE_REPLACED = 4409


def _listen_address(listen: str) -> tuple[str, int]:
    host, _, port = listen.rpartition(":")
    try:
        return host or "127.0.0.1", int(port)
    except ValueError:
        raise FatalError(f"listen must be HOST:PORT, got {listen!r}") from None


class UnitServer:
    def __init__(self, link: WsLink, listen: str) -> None:
        self.link = link
        self.host, self.port = _listen_address(listen)
        self.router = TopicRouter()
        self._conns: dict[str, ServerConnection] = {}
        self._server: Server | None = None
        link.on_event = self._from_above
        link.on_routes = self._routes
        link.on_open = self._replay

    async def start(self) -> None:
        try:
            self._server = await serve(self._serve, self.host, self.port, compression=None)
        except OSError as exc:
            raise FatalError(f"cannot listen on {self.host}:{self.port}: {exc}") from exc
        self.port = self._server.sockets[0].getsockname()[1] if self.port == 0 else self.port
        log.info("local units: ws://%s:%d/?vehicle_id=...", self.host, self.port)

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()

    # -- one unit -------------------------------------------------------------
    async def _serve(self, conn: ServerConnection) -> None:
        query = parse_qs(urlsplit(conn.request.path if conn.request else "").query)
        vehicle_id = (query.get("vehicle_id") or [""])[0]
        if not re.fullmatch(ID_PATTERN, vehicle_id):
            await conn.close(CLOSE_BAD_REQUEST, "connect with ?vehicle_id=<the unit's vehicle>")
            return
        former = self._conns.get(vehicle_id)
        self._conns[vehicle_id] = conn
        if former is not None:
            await former.close(CLOSE_REPLACED, "another connection took this unit")
        self.router.add(vehicle_id)
        log.info("local unit %s connected", vehicle_id)
        try:
            async for frame in conn:
                if isinstance(frame, str):
                    await self._op(vehicle_id, conn, frame)
        except ConnectionClosed:
            pass
        finally:
            if self._conns.get(vehicle_id) is conn:
                del self._conns[vehicle_id]
                await self._gone(vehicle_id)

    async def _gone(self, vehicle_id: str) -> None:
        unit = self.router.drop(vehicle_id)
        if unit is not None and unit.consumes and self.link.connected:
            with contextlib.suppress(AgentError):
                op = {"op": "unsubscribe", "vehicle_id": vehicle_id}
                await self.link.send({**op, "topics": sorted(unit.consumes)})

    async def _op(self, vehicle_id: str, conn: ServerConnection, frame: str) -> None:
        try:
            op = parse_client_op(frame)
        except FrameError as exc:
            await _send(conn, exc.reply().frame())
            return
        if isinstance(op, PublishOp | RegisterOp):
            topics = [op.topic] if isinstance(op, PublishOp) else op.topics
            refusal = next((r for t in topics if (r := write_refusal(vehicle_id, t))), None)
            if refusal is not None:
                await self._answer(conn, op.id, ErrorBody(code="forbidden", message=refusal))
                return
        if isinstance(op, PublishOp):
            await self._publish(vehicle_id, op)
            if op.id:
                await _send(conn, AckPush.success(op.id).frame())
            return
        if isinstance(op, RegisterOp):
            self.router.register(vehicle_id, op.topics)
        elif isinstance(op, SubscribeOp):
            self.router.subscribe(vehicle_id, op.topics)
        elif isinstance(op, UnsubscribeOp):
            self.router.unsubscribe(vehicle_id, op.topics)
        upstream = op.model_dump(mode="json", exclude={"id"}, exclude_none=True)
        try:
            ack = await self.link.call({**upstream, "vehicle_id": vehicle_id}, check=False)
        except AgentError as exc:
            error = ErrorBody(code="unavailable", message=f"the cloud link is down: {exc}")
            await self._answer(conn, op.id, error)
            return
        if op.id:
            await _send(conn, ack.model_copy(update={"id": op.id}).frame())

    async def _publish(self, vehicle_id: str, op: PublishOp) -> None:
        delivery = self.router.publish(vehicle_id, op.topic)
        frame = EventPush(topic=op.topic, data=op.data).model_dump_json()
        for other in delivery.local:
            await _send(self._conns.get(other), frame)
        if delivery.up and self.link.connected:
            with contextlib.suppress(AgentError):
                await self.link.send(
                    {"op": "publish", "vehicle_id": vehicle_id, "topic": op.topic, "data": op.data}
                )

    async def _answer(self, conn: ServerConnection, op_id: str | None, error: ErrorBody) -> None:
        if op_id:
            await _send(conn, AckPush.failure(op_id, error).frame())
        else:
            await _send(conn, '{"op":"error","error":' + error.model_dump_json() + "}")

    # -- from above -------------------------------------------------------------
    def _from_above(self, push: EventPush) -> None:
        frame = push.frame()
        for vehicle_id in self.router.from_above(push.topic):
            self._spawn(_send(self._conns.get(vehicle_id), frame))

    def _routes(self, push: RoutesPush) -> None:
        vehicle_id = self.router.routes(push.unit, push.forward_up, push.forward_down)
        if vehicle_id is not None:
            self._spawn(_send(self._conns.get(vehicle_id), push.frame()))

    async def _replay(self) -> None:
        """After a (re)connection: the units' registrations and subscriptions again."""
        for vehicle_id, kind, topics in self.router.replay():
            with contextlib.suppress(AgentError):
                await self.link.send({"op": kind, "vehicle_id": vehicle_id, "topics": topics})

    def _spawn(self, coro: Any) -> None:
        task = asyncio.ensure_future(coro)
        task.add_done_callback(lambda t: t.cancelled() or t.exception())


async def _send(conn: ServerConnection | None, frame: str) -> None:
    if conn is None:
        return
    with contextlib.suppress(ConnectionClosed):
        await conn.send(frame)
