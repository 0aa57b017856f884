"""``/ws/vehicle`` with the ``websockets`` asyncio client: one link, one or many vehicles.

``WsLink`` holds the socket: it connects, and one reader task sorts what
comes in: acks to their waiters, ``command`` and ``control`` pushes to the
vehicle they are for, ``event`` and ``routes`` (and binary media frames) to
the gateway's topic layer. Ops go out with an ``id`` and wait for their
``ack`` (with a timeout), batched with ``batch_tick_s`` (gateways): that
bookkeeping is ``OpChannel``'s (``vehicle_client.transport.ws_ops``).

``WsTransport`` is one vehicle's view of the link and implements
``Transport``: the agent cannot tell it from ``HttpTransport``, except that
``get_control`` answers from the pushes instead of a long poll.

The link opens lazily (on the first op after it closed). A close with
4401/4403/4409 is fatal for good; any other close, a refused connection or
an op not acked in time fails the waiting calls with ``RetryableError``, and
the agent's reconnect loop (backoff and jitter) takes over. A socket the
server would not upgrade raises ``WsUnavailable``: HTTP may still work.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable
from typing import Any, TypeVar

import websockets
from pydantic import BaseModel, ValidationError
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI

from fleet_protocol import (
    CommandObject,
    ControlInfo,
    FailsafePolicy,
    GetControlResult,
    HeartbeatResult,
    StartInstance,
    StartInstanceResult,
    UpdateFbMessage,
    UpdateFbMessageResult,
    UpdateParam,
    UpdateParamResult,
)
from fleet_protocol.ws import (
    AbortPush,
    AckPush,
    CommandPush,
    ControlPush,
    EventPush,
    FailsafePush,
    RoutesPush,
)
from vehicle_client.errors import AgentError, FatalError, RetryableError
from vehicle_client.transport.wire import PushError, close_error, parse_push, ws_url
from vehicle_client.transport.ws_ops import OpChannel, Socket

log = logging.getLogger(__name__)
M = TypeVar("M", bound=BaseModel)

#: Seconds an op may wait for its ack before the link counts as broken.
ACK_TIMEOUT_S = 10.0
OPEN_TIMEOUT_S = 10.0


class WsUnavailable(RetryableError):
    """The server (or a proxy before it) would not open a WebSocket; HTTP may work."""


class WsLink:
    """One upstream WebSocket, shared by every vehicle of an agent or gateway."""

    def __init__(
        self,
        server: str,
        token: str,
        *,
        batch_tick_s: float = 0.0,
        ack_timeout_s: float = ACK_TIMEOUT_S,
        ping_interval_s: float = 10.0,
    ) -> None:
        if not token:
            raise FatalError("no token: give --token (or FLEET_AGENT_TOKEN)")
        self.url = ws_url(server)
        self._headers = {"Authorization": f"Bearer {token}"}
        self.ping_interval_s = ping_interval_s
        self._sock: Socket | None = None
        self._opening = asyncio.Lock()
        self._fatal: FatalError | None = None
        self._ops = OpChannel(
            batch_tick_s=batch_tick_s,
            ack_timeout_s=ack_timeout_s,
            current=lambda: self._sock,
            broken=self._closed,
        )
        self._reader: asyncio.Task[None] | None = None
        self._vehicles: dict[str, WsTransport] = {}
        self._vehicle_of: dict[str, str] = {}  # instance_id -> vehicle_id
        self.opened = 0
        #: Gateways' topic layer: events and routes from above, and a hook run
        #: after each (re)connection, to register and subscribe again.
        self.on_event: Callable[[EventPush], None] | None = None
        self.on_routes: Callable[[RoutesPush], None] | None = None
        #: Binary (media) frames from above, as they came.
        self.on_media: Callable[[bytes], None] | None = None
        self.on_open: Callable[[], Awaitable[None]] | None = None

    @property
    def frames_out(self) -> int:
        """Frames written on the link so far."""
        return self._ops.frames_out

    @property
    def connected(self) -> bool:
        return self._sock is not None and self._sock.error is None

    def vehicle(self, vehicle_id: str) -> WsTransport:
        """The ``Transport`` for one vehicle on this link."""
        return self._vehicles.setdefault(vehicle_id, WsTransport(self, vehicle_id))

    # -- connection -----------------------------------------------------------
    async def open(self) -> None:
        """Open the socket now if it is not (``WsUnavailable``: no WebSocket here;
        ``RetryableError``: the server cannot be reached)."""
        await self._open()

    async def _open(self) -> Socket:
        if self._fatal is not None:
            raise self._fatal
        sock = self._sock
        if sock is not None and sock.error is None:
            return sock
        async with self._opening:
            if self._sock is not None and self._sock.error is None:
                return self._sock
            try:
                ws = await websockets.connect(
                    self.url,
                    additional_headers=self._headers,
                    compression=None,
                    open_timeout=OPEN_TIMEOUT_S,
                    ping_interval=self.ping_interval_s,
                    ping_timeout=self.ping_interval_s,
                    max_size=4 * 2**20,
                )
            except (InvalidHandshake, InvalidURI) as exc:
                raise WsUnavailable(f"{self.url}: no WebSocket: {exc}") from exc
            except (OSError, TimeoutError) as exc:
                raise RetryableError(f"{self.url}: {type(exc).__name__}: {exc}") from exc
            self._sock = Socket(ws)
            self.opened += 1
            self._reader = asyncio.create_task(self._read(self._sock), name="ws-reader")
            log.info("WebSocket open: %s", self.url)
        if self.on_open is not None:
            await self.on_open()
        return self._sock

    async def aclose(self) -> None:
        self._ops.cancel()
        if self._reader is not None:
            self._reader.cancel()
        sock, self._sock = self._sock, None
        if sock is not None:
            with contextlib.suppress(Exception):
                await sock.ws.close()
            self._closed(sock, RetryableError("the link was closed"))

    def _closed(self, sock: Socket, error: AgentError) -> None:
        if sock.error is not None:
            return
        sock.error = error
        sock.closed.set()
        if isinstance(error, FatalError):
            self._fatal = error
        self._ops.fail_all(error)
        for vehicle in self._vehicles.values():
            vehicle.wake.set()

    # -- ops ------------------------------------------------------------------
    async def call(
        self, op: dict[str, Any], what: str | None = None, *, check: bool = True
    ) -> AckPush:
        """Send ``op`` with a fresh id; its ack (``ok: true``), or the matching error
        (``check=False``: the ack as it came, ``ok: false`` included)."""
        return await self._ops.call(await self._open(), op, what, check=check)

    async def send(self, op: dict[str, Any]) -> None:
        """Send an op without an id (no ack; a failure comes back as an ``error`` push)."""
        await self._ops.send(await self._open(), op)

    async def send_media(self, frame: bytes) -> None:
        """A binary frame on the open socket; never opens one (a media frame is not
        worth a reconnection: the next one will do)."""
        sock = self._sock
        if sock is None or sock.error is not None:
            raise RetryableError("the link is down")
        await self._ops.write(sock, frame)

    # -- pushes -----------------------------------------------------------------
    async def _read(self, sock: Socket) -> None:
        error: AgentError
        try:
            async for frame in sock.ws:
                self._dispatch(frame)
            error = close_error(sock.ws.close_code, sock.ws.close_reason)
        except ConnectionClosed:
            error = close_error(sock.ws.close_code, sock.ws.close_reason)
        except Exception as exc:  # a bug here must not leave waiters hanging
            log.exception("WebSocket reader failed")
            error = RetryableError(f"WebSocket reader failed: {exc!r}")
        log.warning("WebSocket closed: %s", error)
        self._closed(sock, error)

    def _dispatch(self, frame: str | bytes) -> None:
        if isinstance(frame, bytes):
            if self.on_media is not None:
                self.on_media(frame)
            return
        try:
            push = parse_push(frame)
        except PushError as exc:
            log.warning("%s: %s", self.url, exc)
            return
        match push:
            case AckPush():
                op = self._ops.settle(push)
                if op is None:
                    return  # its waiter gave up
                if push.ok and op["op"] == "start_instance":
                    # Before any push for the instance is read: route them.
                    self._vehicle_of[str(getattr(push, "instance_id", ""))] = op["vehicle_id"]
            case CommandPush():
                vehicle = self._for_instance(push.instance_id)
                if vehicle is not None:
                    vehicle.inbox.append(push)
                    vehicle.wake.set()
            case AbortPush():
                vehicle = self._for_instance(push.instance_id)
                if vehicle is not None:
                    vehicle.aborts.extend(push.command_ids)
                    vehicle.wake.set()
            case ControlPush():
                vehicle = self._for_instance(push.instance_id)
                if vehicle is not None:
                    vehicle.set_control(push.control)
            case FailsafePush():
                vehicle = self._for_instance(push.instance_id)
                if vehicle is not None:
                    vehicle.failsafe = push.failsafe  # handed to the agent by get_control
                    vehicle.wake.set()
            case EventPush():
                if self.on_event is not None:
                    self.on_event(push)
            case RoutesPush():
                if self.on_routes is not None:
                    self.on_routes(push)
            case _:
                log.warning("%s: %s", self.url, frame[:300])

    def _for_instance(self, instance_id: str) -> WsTransport | None:
        vehicle_id = self._vehicle_of.get(instance_id)
        return self._vehicles.get(vehicle_id) if vehicle_id else None


class WsTransport:
    """One vehicle on a ``WsLink``: the ``Transport`` the agent uses."""

    kind = "ws"

    def __init__(self, link: WsLink, vehicle_id: str) -> None:
        self.link = link
        self.vehicle_id = vehicle_id
        self.inbox: list[CommandObject] = []
        self.wake = asyncio.Event()
        self.control: ControlInfo | None = None
        self.on_control: Callable[[ControlInfo | None], None] | None = None
        #: A policy pushed and not yet handed to the agent.
        self.failsafe: FailsafePolicy | None = None
        #: Commands the server ended since (``abort`` pushes), not yet handed to the agent.
        self.aborts: list[str] = []

    def set_control(self, control: ControlInfo | None) -> None:
        changed = control != self.control
        self.control = control
        if changed and self.on_control is not None:
            self.on_control(control)

    async def _op(self, name: str, body: BaseModel | dict[str, Any], answer: type[M]) -> M:
        fields = (
            body.model_dump(mode="json", exclude_none=True) if isinstance(body, BaseModel) else body
        )
        ack = await self.link.call({"op": name, **fields}, f"{self.vehicle_id}: {name}")
        try:
            return answer.model_validate(ack.model_dump(exclude={"op", "id", "ok", "error"}))
        except ValidationError as exc:
            raise RetryableError(f"{name}: unreadable ack: {exc}") from exc

    async def start_instance(self, body: StartInstance) -> StartInstanceResult:
        self.inbox.clear()
        res = await self._op("start_instance", body, StartInstanceResult)
        self.set_control(res.control)
        return res

    async def finish_instance(self, instance_id: str) -> None:
        await self.link.call({"op": "finish_instance", "instance_id": instance_id})

    async def heartbeat(self, instance_id: str) -> HeartbeatResult:
        return await self._op("heartbeat", {"instance_id": instance_id}, HeartbeatResult)

    async def update_param(self, body: UpdateParam) -> UpdateParamResult:
        return await self._op("update_param", body, UpdateParamResult)

    async def update_fbmessage(self, body: UpdateFbMessage) -> UpdateFbMessageResult:
        return await self._op("update_fbmessage", body, UpdateFbMessageResult)

    async def get_control(self, instance_id: str, wait_s: float) -> GetControlResult:
        """The commands pushed since the last call; waits for one (or the link's end).

        ``wait_s`` does not apply: an empty answer would claim contact with
        the server that the socket has not shown.
        """
        sock = await self.link._open()
        while not self.inbox and self.failsafe is None and not self.aborts:
            if sock.error is not None:
                raise sock.error
            self.wake.clear()
            await self.wake.wait()
        commands, self.inbox = self.inbox, []
        failsafe, self.failsafe = self.failsafe, None
        aborts, self.aborts = self.aborts, []
        return GetControlResult.model_construct(commands=commands, failsafe=failsafe, abort=aborts)

    async def aclose(self) -> None:
        await self.link.aclose()
