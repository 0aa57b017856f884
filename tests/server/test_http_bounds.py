"""The HTTP protocol's bounds (server/api/http_head.py), on a real uvicorn: a request head
over 64 KB is refused (400) rather than held in memory without end, a head or a body that
stalls closes its connection (slowloris), and neither touches a request that comes whole
nor a WebSocket (upgraded from HTTP)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import httpx
import pytest
from prometheus_client.parser import text_string_to_metric_families

from server.api import http_head
from server.settings import Settings
from tests.factories import ADMIN_TOKEN
from tests.live import call, connect, serve

pytestmark = pytest.mark.usefixtures("store_backend")


async def _exchange(base: str, *parts: bytes) -> bytes:
    """Send ``parts`` on a raw connection; all that comes back until the server closes it
    (by a deadline)."""
    host, port = base.removeprefix("http://").split(":")
    reader, writer = await asyncio.open_connection(host, int(port))
    try:
        for part in parts:
            writer.write(part)
            await writer.drain()
        async with asyncio.timeout(10):
            return await reader.read()  # to the end: the server closed it
    finally:
        writer.close()


async def test_a_head_over_64_kb_is_refused_not_held(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base:
        big = b"X-Big: " + b"a" * (http_head.MAX_HEAD_BYTES + 1) + b"\r\n"
        answer = await _exchange(base, b"GET /healthz HTTP/1.1\r\nHost: t\r\n", big)
        assert answer.startswith(b"HTTP/1.1 400") and b"Invalid HTTP request" in answer
        whole = b"GET /healthz HTTP/1.1\r\nHost: t\r\nConnection: close\r\n\r\n"
        fine = await _exchange(base, whole)
        assert fine.startswith(b"HTTP/1.1 200")


async def test_a_stalled_head_or_body_closes_its_connection(
    make_settings: Callable[..., Settings], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(http_head, "HEAD_TIMEOUT_S", 0.5)
    monkeypatch.setattr(http_head, "BODY_IDLE_S", 0.5)
    async with serve(make_settings()) as base:
        async with await connect(base, "/ws/client", ADMIN_TOKEN) as ws:
            # Half a head, then nothing: closed without an answer.
            assert await _exchange(base, b"GET /healthz HTTP/1.1\r\nHost: t\r\n") == b""
            # A body that says 10 bytes and sends 2: closed, and no 500 for it.
            head = b"POST /auth/token HTTP/1.1\r\nHost: t\r\nContent-Type: application/json\r\n"
            stalled = await _exchange(base, head + b"Content-Length: 10\r\n\r\n{}")
            assert b" 500 " not in stalled
            # Both bounds have passed (each close above took one): the WebSocket, upgraded
            # from HTTP before them, is not HTTP's to close.
            assert (await call(ws, "subscribe", "s", topics=["fleet"]))["ok"] is True


async def test_a_client_gone_mid_body_is_no_fault_of_the_server(
    make_settings: Callable[..., Settings],
) -> None:
    """A login whose client hung up halfway through its body: a 500 and two tracebacks in
    the log before (anyone could set off the server's alerts)."""
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        head = b"POST /auth/token HTTP/1.1\r\nHost: t\r\nContent-Type: application/json\r\n"
        host, port = base.removeprefix("http://").split(":")
        _, writer = await asyncio.open_connection(host, int(port))
        writer.write(head + b'Content-Length: 100\r\n\r\n{"a":')
        await writer.drain()
        writer.close()

        async def counted(status: str) -> float:
            text = (await c.get("/metrics")).text
            for family in text_string_to_metric_families(text):
                for s in family.samples:
                    labels = s.labels
                    if labels.get("route") == "/auth/token" and labels.get("status") == status:
                        return float(s.value)
            return 0.0

        async with asyncio.timeout(10):
            while not await counted("400"):  # noqa: ASYNC110 (deadline poll)
                await asyncio.sleep(0.05)
        assert await counted("500") == 0
