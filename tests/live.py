"""A real uvicorn serving the app on a free loopback port, in the test's event loop."""

from __future__ import annotations

import asyncio
import json
import socket
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import httpx
import uvicorn
import websockets

from server.api.ws_direct import uvicorn_ws_options
from server.app import create_app
from server.settings import Settings
from server.storage import Store


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@asynccontextmanager
async def serve(
    settings: Settings,
    store: Store | None = None,
    port: int | None = None,
    app: Any = None,
    **uvicorn_options: Any,
) -> AsyncIterator[str]:
    """Yields the base URL (``http://127.0.0.1:PORT``) while the server runs (on ``store``
    when given: the caller's open store, which it closes; on ``port`` when given; ``app``:
    the app to serve, made by the caller who wants to reach its services; the rest: more
    of uvicorn's options)."""
    port = port or free_port()
    config = uvicorn.Config(
        app or create_app(settings, store=store),
        host="127.0.0.1",
        port=port,
        log_level="warning",
        **uvicorn_ws_options(),
        lifespan="on",
        # A test's client may sit idle for longer than uvicorn's 5 s while it waits on
        # the server (presence moving on): its kept-alive connection is not dropped.
        timeout_keep_alive=120,
        **uvicorn_options,
    )
    server = uvicorn.Server(config)
    task = asyncio.create_task(server.serve())
    try:
        async with asyncio.timeout(20):
            while not server.started:
                if task.done():
                    task.result()
                await asyncio.sleep(0.01)
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        await asyncio.wait_for(task, 20)


def ws_url(base: str, path: str, token: str | None = None) -> str:
    url = base.replace("http://", "ws://") + path
    return f"{url}?token={token}" if token else url


async def recv_json(ws: Any, within_s: float = 10) -> dict[str, Any]:
    frame = await asyncio.wait_for(ws.recv(), within_s)
    assert isinstance(frame, str), frame
    result: dict[str, Any] = json.loads(frame)
    return result


async def recv_until(ws: Any, predicate: Any, within_s: float = 10) -> dict[str, Any]:
    """The first JSON frame that satisfies ``predicate`` (others are skipped) by a deadline."""
    async with asyncio.timeout(within_s):
        while True:
            frame = await recv_json(ws, within_s)
            if predicate(frame):
                return frame


async def call(ws: Any, op: str, op_id: str, **fields: Any) -> dict[str, Any]:
    """Send an op with an id and wait for its ack (pushes in between are skipped)."""
    await ws.send(json.dumps({"op": op, "id": op_id, **fields}))
    return await recv_until(ws, lambda f: f.get("op") == "ack" and f.get("id") == op_id)


async def connect(base: str, path: str, token: str) -> Any:
    return await websockets.connect(
        ws_url(base, path),
        compression=None,
        additional_headers={"Authorization": f"Bearer {token}"},
    )


def http(base: str, token: str) -> httpx.AsyncClient:
    return httpx.AsyncClient(
        base_url=base, headers={"Authorization": f"Bearer {token}"}, timeout=10
    )
