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

import contextlib
from collections.abc import Awaitable, Callable, MutableMapping
from typing import TYPE_CHECKING, Any

from starlette.datastructures import Headers, QueryParams

from fleet_protocol.links import CLOSE_FORBIDDEN, CLOSE_TRY_AGAIN, CLOSE_UNAUTHORIZED
from server.api.deps import bearer_token
from server.bus.outbox import Frame, Outbox
from server.errors import FleetError, Unauthorized
from server.services.auth import digest
from server.services.live import Connection
from server.services.live_ops import OpRunner

if TYPE_CHECKING:
    from server.container import Services

Scope = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[MutableMapping[str, Any]]]
Send = Callable[[MutableMapping[str, Any]], Awaitable[None]]

#: path -> the kind of socket it serves (``vehicle``: vehicle and gateway tokens)
LIVE_PATHS = {"/ws/vehicle": "vehicle", "/ws/client": "client"}


def _token(scope: Scope) -> str | None:
    """The bearer token, or ``?token=`` on the URL (browsers cannot set headers)."""
    query = QueryParams(scope.get("query_string", b"").decode("latin-1"))
    return bearer_token(Headers(scope=scope)) or query.get("token") or None


async def serve_live(services: Services, scope: Scope, receive: Receive, send: Send) -> None:
    """One WebSocket on ``scope["path"]`` (a key of :data:`LIVE_PATHS`), until it closes."""
    kind = LIVE_PATHS[scope["path"]]
    if (await receive())["type"] != "websocket.connect":
        return
    await send({"type": "websocket.accept"})

    async def close(code: int, reason: str) -> None:
        with contextlib.suppress(Exception):  # already closed, or the client went
            await send({"type": "websocket.close", "code": code, "reason": reason})

    token = _token(scope)
    try:
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
    token_key = digest(token)  # checked again on every frame, hashed once
    conn = Connection(
        principal, Outbox(push, max_size=services.settings.ws_queue_size), close, kind
    )
    services.live.add(conn)
    ops = OpRunner(services, conn)
    auth, live = services.auth, services.live
    try:
        while not conn.closed:
            message = await receive()
            if message["type"] != "websocket.receive":
                break  # websocket.disconnect
            try:  # on every frame; a revoked token's entry is gone from the cache
                known = auth.cached(token_key)
                conn.principal = known or await auth.authenticate_digest(token_key)
            except Unauthorized:
                await live.close(conn, CLOSE_UNAUTHORIZED, "the token is no longer valid")
                break
            if kind == "vehicle":
                live.touch(conn)
            text = message.get("text")
            if text is not None:
                await ops.text(text)
            else:
                data = message.get("bytes")
                if data is not None:
                    await ops.binary(data)
    except (OSError, RuntimeError):
        pass  # the client went while a frame was sent (uvicorn's ClientDisconnected)
    finally:
        await live.drop(conn)
