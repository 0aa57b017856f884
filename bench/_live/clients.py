"""The bench's clients: WebSocket helpers, a raw HTTP/1.1 client, an answer's check, the
event loop runner."""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import time
from collections.abc import Awaitable, Callable, Sequence
from typing import Any

import httpx
import websockets
from websockets.asyncio.client import ClientConnection


def ok(r: httpx.Response) -> httpx.Response:
    """``r``, when it is not an error; else RuntimeError naming the call and the answer."""
    if r.status_code >= 400:
        raise RuntimeError(f"{r.request.method} {r.request.url.path}: {r.status_code} {r.text}")
    return r


async def ws_connect(url: str, token: str | None = None) -> ClientConnection:
    headers = {"Authorization": f"Bearer {token}"} if token else None
    return await websockets.connect(
        url,
        compression=None,
        additional_headers=headers,
        ping_interval=None,
        max_size=4 * 1024 * 1024,
        open_timeout=60,
        close_timeout=2,
    )


async def recv_json(ws: ClientConnection) -> dict[str, Any]:
    frame = await ws.recv()
    result: dict[str, Any] = json.loads(frame)
    return result


async def ws_call(ws: ClientConnection, op: str, op_id: str, **fields: Any) -> dict[str, Any]:
    """Send an op with an id, read until its ack (other frames skipped), within 30 s."""
    await ws.send(json.dumps({"op": op, "id": op_id, **fields}))
    async with asyncio.timeout(30):
        while True:
            frame = await recv_json(ws)
            if frame.get("op") == "ack" and frame.get("id") == op_id:
                return frame


async def next_event(ws: ClientConnection) -> str:
    """The next ``event`` push (``routes`` pushes and the like are skipped)."""
    while True:
        frame = await ws.recv()
        if isinstance(frame, str) and frame.startswith('{"op":"event"'):
            return frame
        if isinstance(frame, str) and frame.startswith(('{"op":"lagging"', '{"op":"error"')):
            raise RuntimeError(f"unexpected frame: {frame[:200]!r}")


async def time_hops(
    send: Callable[[str], Awaitable[None]],
    arrival: Callable[[], Awaitable[Any]],
    frame: str,
    count: int,
    warmup: int,
) -> list[int]:
    """One message in flight: ns from before each ``send`` to its ``arrival``, warm-up dropped."""
    samples: list[int] = []
    async with asyncio.timeout(300):
        for _ in range(warmup + count):
            t0 = time.perf_counter_ns()
            await send(frame)
            await arrival()
            samples.append(time.perf_counter_ns() - t0)
    return samples[warmup:]


async def close_all(sockets: Sequence[ClientConnection]) -> None:
    async def one(ws: ClientConnection) -> None:
        with contextlib.suppress(Exception):
            await ws.close()

    for start in range(0, len(sockets), 500):
        await asyncio.gather(*(one(ws) for ws in sockets[start : start + 500]))


class RawHttp:
    """A minimal HTTP/1.1 keep-alive JSON client (less client time in the figures than httpx)."""

    def __init__(self, port: int, token: str) -> None:
        self.port = port
        self.token = token
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None

    async def open(self) -> RawHttp:
        self._reader, self._writer = await asyncio.open_connection("127.0.0.1", self.port)
        sock = self._writer.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return self

    async def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            with contextlib.suppress(Exception):
                await self._writer.wait_closed()

    async def request(self, method: str, path: str, body: Any = None) -> tuple[int, Any]:
        """One request; on a connection the server closed while idle, reopened once."""
        try:
            return await self._request(method, path, body)
        except (asyncio.IncompleteReadError, ConnectionError):
            await self.close()
            await self.open()
            return await self._request(method, path, body)

    async def _request(self, method: str, path: str, body: Any) -> tuple[int, Any]:
        assert self._reader is not None and self._writer is not None
        data = json.dumps(body).encode() if body is not None else b""
        head = (
            f"{method} {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n"
            f"Authorization: Bearer {self.token}\r\n"
            f"Content-Type: application/json\r\nContent-Length: {len(data)}\r\n\r\n"
        )
        self._writer.write(head.encode() + data)
        raw = await self._reader.readuntil(b"\r\n\r\n")
        lines = raw.decode("latin-1").split("\r\n")
        status = int(lines[0].split(" ", 2)[1])
        length = 0
        for line in lines[1:]:
            name, _, value = line.partition(":")
            if name.strip().lower() == "content-length":
                length = int(value.strip())
        payload = await self._reader.readexactly(length) if length else b""
        return status, json.loads(payload) if payload else None


def run_async(coro: Awaitable[Any]) -> Any:
    try:
        import uvloop

        with asyncio.Runner(loop_factory=uvloop.new_event_loop) as runner:
            return runner.run(coro)  # type: ignore[arg-type]
    except ImportError:
        return asyncio.run(coro)  # type: ignore[arg-type]
