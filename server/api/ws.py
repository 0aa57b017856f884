"""``/ws/vehicle`` and ``/ws/client``: accept, authenticate, then parse -> service -> send.

The two endpoints are plain ASGI handlers that :class:`server.app.FleetApp`
calls straight from its ``__call__`` (``LIVE_PATHS``), ahead of the
middleware and routing stack the HTTP routes need: that stack does nothing
for a WebSocket, but every frame received would resume its twenty-odd
coroutine frames, and every frame sent would pass three wrappers. The
messages are the ASGI WebSocket ones (``websocket.connect``, ``.accept``,
``.receive``, ``.send``, ``.close``, ``.disconnect``).
"""

from __future__ import annotations

import asyncio
import logging
from collections import deque
from collections.abc import Awaitable, Callable, Coroutine, Generator, MutableMapping
from typing import Any

from pydantic import ValidationError
from starlette.datastructures import QueryParams

from fleet_protocol import utcnow
from fleet_protocol.links import (
    CLOSE_FORBIDDEN,
    CLOSE_TOO_SLOW,
    CLOSE_TRY_AGAIN,
    CLOSE_UNAUTHORIZED,
)
from fleet_protocol.ws import AckPush, AuthOp
from server.api.deps import bearer_token
from server.api.live_conn import Connection
from server.api.live_hub import LiveHub
from server.api.outbox import Frame, LazyEvent, Outbox
from server.api.ws_direct import DIRECT
from server.api.ws_ops import OpRunner
from server.errors import FleetError, Unauthorized
from server.services.registry import Services
from server.services.tokens import digest

Scope = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[MutableMapping[str, Any]]]
Send = Callable[[MutableMapping[str, Any]], Awaitable[None]]

#: path -> the kind of socket it serves (``vehicle``: vehicle and gateway tokens)
LIVE_PATHS = {"/ws/vehicle": "vehicle", "/ws/client": "client"}
#: The WebSocket close code for a fault of the server's (RFC 6455: internal error).
CLOSE_INTERNAL_ERROR = 1011
#: How long a closing handshake may wait on a socket that does not take it before the
#: connection is dropped.
CLOSE_WAIT_S = 2.0

log = logging.getLogger("fleet.live")


def _token(scope: Scope) -> str | None:
    """The bearer token, or ``?token=`` on the URL; None: the first frame will carry it
    (``{"op": "auth", "token": ...}``, the way for browsers, which cannot set headers and
    should not put secrets in URLs)."""
    query = QueryParams(scope.get("query_string", b"").decode("latin-1"))
    return bearer_token(scope) or query.get("token") or None


async def serve_live(
    services: Services, hub: LiveHub, scope: Scope, receive: Receive, send: Send
) -> None:
    """One WebSocket on ``scope["path"]`` (a key of :data:`LIVE_PATHS`), until it closes."""
    kind = LIVE_PATHS[scope["path"]]
    if (await receive())["type"] != "websocket.connect":
        return
    await send({"type": "websocket.accept"})

    direct = scope.get("extensions", {}).get(DIRECT)

    async def close(code: int, reason: str) -> None:
        try:  # a reader that does not read holds the closing handshake up: not for long
            await asyncio.wait_for(
                send({"type": "websocket.close", "code": code, "reason": reason}), CLOSE_WAIT_S
            )
        except TimeoutError:
            if direct is not None:
                direct["abort"]()
        except Exception:  # already closed, or the client went
            pass

    token = _token(scope)
    auth_id: str | None = None
    if token is None:  # no header, no ?token=: the first frame says who it is
        first = await _first_frame(receive, services.settings.ws_auth_wait_s)
        if first is None:
            await close(
                CLOSE_UNAUTHORIZED, 'a token is required: send {"op": "auth", "token": ...}'
            )
            return
        token, auth_id = first.token, first.id
    try:
        services.readiness.require()
        principal = await services.auth.authenticate(token)
    except Unauthorized as exc:
        await close(CLOSE_UNAUTHORIZED, exc.message)
        return
    except FleetError as exc:
        await close(CLOSE_TRY_AGAIN, exc.message)
        return
    if (kind == "vehicle") != (principal.kind in ("vehicle", "gateway")):
        await close(CLOSE_FORBIDDEN, f"/ws/{kind} is not for {principal.kind} tokens")
        return

    async def push(frame: Frame) -> None:
        if isinstance(frame, bytes):
            await send({"type": "websocket.send", "bytes": frame})
        else:
            await send({"type": "websocket.send", "text": frame})

    assert token is not None  # authenticate refuses a missing one
    token_key = digest(token)  # hashed once
    settings = services.settings

    def too_slow() -> None:
        reason = f"reading too slowly: over {settings.ws_queue_bytes} bytes waited"
        hub.close_soon(conn, CLOSE_TOO_SLOW, reason)

    outbox = Outbox(
        push,
        send_nowait=direct["send_nowait"] if direct is not None else None,
        max_size=settings.ws_queue_size,
        max_bytes=settings.ws_queue_bytes,
        on_overflow=too_slow,
        on_written=hub.operator_written,
    )
    conn = Connection(principal, outbox, close, kind, digest=token_key)
    hub.add(conn)
    expiry = None
    if principal.expires_at is not None:  # a session token: the socket ends with it
        left = (principal.expires_at - utcnow()).total_seconds()
        expiry = asyncio.get_running_loop().call_later(
            max(0.0, left), hub.close_soon, conn, CLOSE_UNAUTHORIZED, "the token has expired"
        )
    if auth_id is not None:
        outbox.put(AckPush.success_frame(auth_id, {"kind": principal.kind}))
    frames = _Frames(services, hub, conn, token_key)
    inbox = None if direct is None else _DirectInbox(frames, direct)
    try:
        if inbox is not None:
            inbox.attach()
        while not conn.closed:
            message = await receive()
            if message["type"] != "websocket.receive":
                break  # websocket.disconnect
            data = message.get("text")
            if data is None:
                data = message.get("bytes")
            if data is None:
                continue
            if inbox is not None:
                inbox.feed(data)  # not expected once attached: kept in order all the same
            else:
                await frames.handle(data)
        if inbox is not None:
            await inbox.idle.wait()  # what came before the disconnect is handled first
    except (OSError, RuntimeError):
        pass  # the client went while a frame was sent (uvicorn's ClientDisconnected)
    except Exception:
        log.exception("live socket: handling a message failed")
        await hub.close(conn, CLOSE_INTERNAL_ERROR, "internal error")
    finally:
        if expiry is not None:
            expiry.cancel()
        await hub.drop(conn)


async def _first_frame(receive: Receive, wait_s: float) -> AuthOp | None:
    """The ``auth`` op a socket opened without a token sends first; None if it sends
    anything else, nothing within ``wait_s``, or goes."""
    try:
        message = await asyncio.wait_for(receive(), wait_s)
    except TimeoutError:
        return None
    text = message.get("text") if message["type"] == "websocket.receive" else None
    if not isinstance(text, str) or len(text) > 4096:
        return None
    try:
        return AuthOp.model_validate_json(text)
    except ValidationError:
        return None


class _Frames:
    """What is done with each message of one socket: the token checked again (a revoked
    token closes the socket), contact counted on a vehicle's socket, then the op."""

    def __init__(self, services: Services, hub: LiveHub, conn: Connection, token_key: str) -> None:
        self.auth = services.auth
        self.live = hub
        self.conn = conn
        self.ops = OpRunner(services, hub, conn)
        self.token_key = token_key
        self.vehicle = conn.kind == "vehicle"

    async def handle(self, data: str | bytes) -> None:
        rest = self.now(data)
        if rest is not None:
            await rest

    def now(self, data: str | bytes) -> Awaitable[None] | None:
        """Handle ``data`` within this call as far as nothing waits; what is left, if any."""
        known = self.auth.cached(self.token_key)
        if known is None:
            return self._after_lookup(data)  # the token is looked up again: all of it waits
        self.conn.principal = known
        return self._op_now(data)

    async def _after_lookup(self, data: str | bytes) -> None:
        try:  # a revoked token's entry is gone from the cache, and the lookup refuses it
            self.conn.principal = await self.auth.authenticate_digest(self.token_key)
        except Unauthorized:
            await self.live.close(self.conn, CLOSE_UNAUTHORIZED, "the token is no longer valid")
            return
        rest = self._op_now(data)
        if rest is not None:
            await rest

    def _op_now(self, data: str | bytes) -> Awaitable[None] | None:
        if isinstance(data, str):  # counts as the vehicle's contact (text_now says when)
            return self.ops.text_now(data, contact=self.vehicle)
        if self.vehicle:
            self.live.touch(self.conn)
        return self.ops.binary_now(data)


class _DirectInbox:
    """Messages handed over by the server as they are read (``server.api.ws_direct``).

    Each is handled at once, in the server's read callback, as far as nothing
    has to wait: a publish goes out to its subscribers before the socket is
    read again, with no task switch. A message whose handling waits (the
    store, another replica, a token to look up) is finished by a task, and
    the ones after it wait their turn in order; reading is paused once
    :data:`_HELD_BEFORE_PAUSE` wait (not at the first: a vehicle's 1 Hz
    ``update_param`` never has one behind it, and pausing and resuming are
    two system calls each time). A burst of more than :data:`_PER_READ`
    messages in one read goes the same way, so that one socket cannot hold
    the others up.
    """

    def __init__(self, frames: _Frames, direct: dict[str, Any]) -> None:
        self.frames = frames
        self._direct = direct
        self._pause: Callable[[], None] = direct["pause"]
        self._resume: Callable[[], None] = direct["resume"]
        self._backlog: deque[str | bytes] = _NO_BACKLOG  # a deque once a message waits
        self._task: asyncio.Task[None] | None = None
        self._stopped = False
        self._loop = asyncio.get_running_loop()
        #: Set while no message waits or is being handled.
        self.idle = LazyEvent()
        self.idle.set()
        #: Ops are run in the read callback up to their first wait only where nothing on
        #: their way needs a running task (a client library's ``asyncio.timeout`` does):
        #: the embedded store and a bus that stays in the process. Elsewhere every op
        #: that is not a local publish is a task's, as uvicorn's own path would have it.
        ops = frames.ops
        self._eager = ops.s.store.kind == "embedded" and not ops.hub.bus.remote

    def _held(self) -> deque[str | bytes]:
        if self._backlog is _NO_BACKLOG:
            self._backlog = deque()
        return self._backlog

    def attach(self) -> None:
        """From now on the server hands each message to :meth:`feed`; those that came
        before are handled first."""
        if self.frames.vehicle:  # a vehicle's ping is contact, as every frame is (API.md)
            self._direct["on_ping"](lambda: self.frames.live.touch(self.frames.conn))
        for early in self._direct["attach"](self.feed):
            self.feed(early)

    def feed(self, data: str | bytes, rank: int = 1) -> None:
        """``rank``: the message's place among those of one read of the socket."""
        if self._stopped or self.frames.conn.closed:
            return
        if self._task is not None:
            self._held().append(data)
            if len(self._backlog) >= _HELD_BEFORE_PAUSE:
                self._pause()  # resumed when the backlog is handled
            return
        if rank > _PER_READ:  # a burst: the other sockets get their turn first
            self._held().append(data)
            self.idle.clear()
            self._task = self._loop.create_task(self._finish(asyncio.sleep(0)))
            return
        try:
            rest = self.frames.now(data)
            if rest is not None and self._eager:
                rest = _run_eagerly(rest)
        except (OSError, RuntimeError):
            self._stopped = True  # as in _finish: the client went while a frame was sent
            return
        except Exception:
            self._fail()
            return
        if rest is not None:
            self.idle.clear()
            self._task = self._loop.create_task(self._finish(rest))

    async def _finish(self, rest: Awaitable[None]) -> None:
        try:
            await rest
            handled = 0
            while self._backlog and not self.frames.conn.closed:
                await self.frames.handle(self._backlog.popleft())
                handled += 1
                if handled % _PER_READ == 0:
                    await asyncio.sleep(0)  # a long backlog does not hold the loop either
        except (OSError, RuntimeError):
            self._stopped = True  # the client went while a frame was sent
        except Exception:
            self._fail()
        finally:
            self._backlog = _NO_BACKLOG
            self._task = None
            self._resume()
            self.idle.set()

    def _fail(self) -> None:
        """A fault of ours: logged, and the socket closed (1011) as uvicorn would."""
        log.exception("live socket: handling a message failed")
        self._stopped = True
        conn = self.frames.conn
        task = self._loop.create_task(
            self.frames.live.close(conn, CLOSE_INTERNAL_ERROR, "internal error")
        )
        _closing.add(task)
        task.add_done_callback(_closing.discard)


def _run_eagerly(pending: Awaitable[None]) -> Awaitable[None] | None:
    """Run a coroutine up to its first wait, here and now: None when it finished without
    one (an op on the embedded store, or one this replica answers from memory: no task
    is made for it), else what is left, for a task to finish (as an eager task would)."""
    if not isinstance(pending, Coroutine):
        return pending
    try:
        first = pending.send(None)
    except StopIteration:
        return None
    return _Resumed(pending, first)


class _Resumed:
    """The rest of a coroutine that :func:`_run_eagerly` ran up to a wait: awaited, it
    hands the task what the coroutine waits for, then carries on with it."""

    __slots__ = ("_coro", "_first")

    def __init__(self, coro: Coroutine[Any, Any, None], first: Any) -> None:
        self._coro, self._first = coro, first

    def __await__(self) -> Generator[Any, Any, None]:
        coro, waiting = self._coro, self._first
        while True:
            try:
                try:
                    answer = yield waiting
                except BaseException as exc:  # cancelled, or closed: the coroutine is told
                    waiting = coro.throw(exc)
                else:
                    waiting = coro.send(answer)
            except StopIteration:
                return


_closing: set[asyncio.Task[None]] = set()
#: A socket's backlog while none waits (a deque is made for the first that does).
_NO_BACKLOG: Any = ()
#: Messages held behind a waiting one before the socket's reading is paused.
_HELD_BEFORE_PAUSE = 16
#: Messages of one read of a socket handled at once; the rest of a burst (a read can
#: carry thousands of small frames) waits for the other sockets' turn.
_PER_READ = 64
