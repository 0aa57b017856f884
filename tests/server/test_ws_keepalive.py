"""Keepalive pings of the live sockets (``server/api/keepalive.py``), seen from a raw
client on the wire: an idle peer is pinged every interval and stays while it answers;
one that does not answer is closed with 1011; one that talks is not pinged at all."""

from __future__ import annotations

import asyncio
import base64
import json
import os
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager

import pytest

from server.settings import Settings
from tests.factories import ADMIN_TOKEN
from tests.live import serve

INTERVAL_S = 0.3


class RawSocket:
    """A WebSocket client frame by frame: it sees the pings and answers them, or not."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader, self.writer = reader, writer
        self.pings = 0

    async def frame(self) -> tuple[int, bytes]:
        """The next frame from the server (it sends them unmasked): opcode, payload."""
        first, second = await self.reader.readexactly(2)
        length = second & 0x7F
        if length == 126:
            length = int.from_bytes(await self.reader.readexactly(2), "big")
        elif length == 127:
            length = int.from_bytes(await self.reader.readexactly(8), "big")
        return first & 0x0F, await self.reader.readexactly(length)

    def send(self, opcode: int, payload: bytes, *, fin: bool = True) -> None:
        """One masked frame of under 126 bytes (``fin=False``: a message's first part)."""
        mask = os.urandom(4)
        masked = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
        first = (0x80 if fin else 0) | opcode
        self.writer.write(bytes((first, 0x80 | len(payload))) + mask + masked)

    async def until(self, opcode: int, *, answer: bool) -> bytes:
        """Frames up to the first of ``opcode``; each ping counted, answered if ``answer``."""
        while True:
            op, payload = await self.frame()
            if op == 0x9:
                self.pings += 1
                if answer:
                    self.send(0xA, payload)
            if op == opcode:
                return payload


@asynccontextmanager
async def raw_client(base: str, token: str | None = ADMIN_TOKEN) -> AsyncIterator[RawSocket]:
    """A raw client on ``/ws/client``, its token in the header (none: it has not said it)."""
    host, port = base.removeprefix("http://").split(":")
    reader, writer = await asyncio.open_connection(host, int(port))
    key = base64.b64encode(os.urandom(16)).decode()
    auth = f"Authorization: Bearer {token}\r\n" if token is not None else ""
    writer.write(
        (
            "GET /ws/client HTTP/1.1\r\n"
            f"Host: {host}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
            f"{auth}\r\n"
        ).encode()
    )
    head = await reader.readuntil(b"\r\n\r\n")
    assert head.startswith(b"HTTP/1.1 101"), head
    try:
        yield RawSocket(reader, writer)
    finally:
        writer.close()


@pytest.fixture
async def base(make_settings: Callable[..., Settings]) -> AsyncIterator[str]:
    async with serve(
        make_settings(), ws_ping_interval=INTERVAL_S, ws_ping_timeout=INTERVAL_S
    ) as url:
        yield url


async def test_an_idle_peer_is_pinged_each_interval_and_stays_while_it_answers(
    base: str,
) -> None:
    async with raw_client(base) as ws:
        started = time.monotonic()
        async with asyncio.timeout(10 * INTERVAL_S):
            for _ in range(4):
                await ws.until(0x9, answer=True)
        assert time.monotonic() - started >= 3 * INTERVAL_S  # one an interval, not more
        # Still served: an op is answered after four pings.
        ws.send(0x1, json.dumps({"op": "unsubscribe", "id": "1", "topics": ["fleet"]}).encode())
        async with asyncio.timeout(5):
            reply = json.loads(await ws.until(0x1, answer=True))
        assert reply.get("id") == "1", reply


async def test_a_peer_that_does_not_answer_is_closed_with_1011(base: str) -> None:
    async with raw_client(base) as ws:
        async with asyncio.timeout(10 * INTERVAL_S):
            payload = await ws.until(0x8, answer=False)
        assert int.from_bytes(payload[:2], "big") == 1011
        assert ws.pings == 1


async def test_a_peer_that_talks_is_not_pinged(base: str) -> None:
    async with raw_client(base) as ws:
        deadline = time.monotonic() + 4 * INTERVAL_S
        n = 0
        while time.monotonic() < deadline:  # an op every third of an interval, each answered
            n += 1
            ws.send(
                0x1, json.dumps({"op": "unsubscribe", "id": str(n), "topics": ["fleet"]}).encode()
            )
            async with asyncio.timeout(5):
                reply = json.loads(await ws.until(0x1, answer=True))
            assert reply.get("id") == str(n), reply
            await asyncio.sleep(INTERVAL_S / 3)  # the peer's cadence, not a wait
        assert ws.pings == 0
