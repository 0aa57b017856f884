"""``/ws/vehicle`` and ``/ws/client``: accept, authenticate, then parse -> service -> send."""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from server.bus.outbox import Frame, Outbox
from server.errors import FleetError, Unauthorized
from server.services.auth import digest
from server.services.live import (
    CLOSE_FORBIDDEN,
    CLOSE_UNAUTHORIZED,
    Connection,
)
from server.services.live_ops import OpRunner

if TYPE_CHECKING:
    from server.container import Services

router = APIRouter(tags=["live"])


@router.websocket("/ws/vehicle")
async def ws_vehicle(websocket: WebSocket) -> None:
    await _serve(websocket, "vehicle")


@router.websocket("/ws/client")
async def ws_client(websocket: WebSocket) -> None:
    await _serve(websocket, "client")


def _token(websocket: WebSocket) -> str | None:
    scheme, _, value = websocket.headers.get("authorization", "").partition(" ")
    if scheme.lower() == "bearer" and value.strip():
        return value.strip()
    return websocket.query_params.get("token") or None


async def _serve(websocket: WebSocket, kind: str) -> None:
    services: Services = websocket.app.state.services
    await websocket.accept()
    token = _token(websocket)
    try:
        principal = await services.auth.authenticate(token)
    except Unauthorized as exc:
        await websocket.close(CLOSE_UNAUTHORIZED, exc.message)
        return
    except FleetError as exc:
        await websocket.close(1013, exc.message)  # try again later
        return
    if (kind == "vehicle") != (principal.kind in ("vehicle", "gateway")):
        await websocket.close(CLOSE_FORBIDDEN, f"/ws/{kind} is not for {principal.kind} tokens")
        return

    async def send(frame: Frame) -> None:
        if isinstance(frame, bytes):
            await websocket.send_bytes(frame)
        else:
            await websocket.send_text(frame)

    async def close(code: int, reason: str) -> None:
        with contextlib.suppress(Exception):
            await websocket.close(code, reason)

    assert token is not None
    token_key = digest(token)  # checked again on every frame, hashed once
    conn = Connection(
        principal, token, Outbox(send, max_size=services.settings.ws_queue_size), close, kind
    )
    services.live.add(conn)
    ops = OpRunner(services, conn)
    try:
        while not conn.closed:
            message = await websocket.receive()
            if message["type"] == "websocket.disconnect":
                break
            try:  # on every frame; a revoked token's entry is gone from the cache
                known = services.auth.cached(token_key)
                conn.principal = known or await services.auth.authenticate_digest(token_key)
            except Unauthorized:
                await services.live.close(conn, CLOSE_UNAUTHORIZED, "the token is no longer valid")
                break
            if kind == "vehicle":
                services.live.touch(conn)
            if message.get("text") is not None:
                await ops.text(message["text"])
            elif message.get("bytes") is not None:
                await ops.binary(message["bytes"])
    except (WebSocketDisconnect, RuntimeError):
        pass
    finally:
        await services.live.drop(conn)
