"""A minimal WebSocket client on an ``asyncio.Protocol``, for the capacity load.

RFC 6455 as far as the load needs it: the HTTP upgrade, text frames masked
with a zero key (which XORs to the payload itself and costs the server the
same unmasking as any other key), frames from the server parsed, close and
ping answered. The ``websockets`` client costs several times as much CPU a
message, and 10,000 vehicles of it filled the bench's core before the
server's: the figures were the generator's. The server sees the same bytes
on the wire either way but the mask.

:class:`RawWebSocket` hands its subclass each text frame (``_message``) and
the socket's end (``_lost``); the vehicles of :mod:`bench._live.loadgen_worker`
are one.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import os
import socket
from typing import cast


def text_frame(payload: bytes) -> bytes:
    """A client's text frame: FIN, masked with the zero key (so the payload goes as it is)."""
    n = len(payload)
    if n < 126:
        head = bytes((0x81, 0x80 | n))
    elif n < 65536:
        head = bytes((0x81, 0xFE)) + n.to_bytes(2, "big")
    else:
        head = bytes((0x81, 0xFF)) + n.to_bytes(8, "big")
    return head + b"\0\0\0\0" + payload


def control_frame(opcode: int, payload: bytes = b"") -> bytes:
    return bytes((0x80 | opcode, 0x80 | len(payload))) + b"\0\0\0\0" + payload


class RawWebSocket(asyncio.Protocol):
    """One client WebSocket: the handshake, frames parsed, close and ping answered."""

    def __init__(self, host: str, port: int, path: str, token: str) -> None:
        self.request = (
            f"GET {path} HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
            "Connection: Upgrade\r\n"
            f"Sec-WebSocket-Key: {base64.b64encode(os.urandom(16)).decode()}\r\n"
            f"Sec-WebSocket-Version: 13\r\nAuthorization: Bearer {token}\r\n\r\n"
        ).encode()
        self.transport: asyncio.Transport | None = None
        self.buf = bytearray()
        self.upgraded = False
        #: Done once the server upgraded the connection (its exception if it did not).
        self.opened: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self.closed = False

    # -- asyncio.Protocol ----------------------------------------------------------------

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.Transport, transport)  # uvloop's is not a subclass
        sock = transport.get_extra_info("socket")
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        transport.write(self.request)

    def connection_lost(self, exc: Exception | None) -> None:
        self._lost(ConnectionError(f"connection lost: {exc!r}"))

    def data_received(self, data: bytes) -> None:
        buf = self.buf
        buf += data
        if not self.upgraded:
            end = buf.find(b"\r\n\r\n")
            if end < 0:
                return
            status = bytes(buf[:end]).split(b"\r\n", 1)[0]
            del buf[: end + 4]
            if b" 101 " not in status:
                self._lost(ConnectionError(f"upgrade refused: {status.decode('latin-1')}"))
                if self.transport is not None:
                    self.transport.close()
                return
            self.upgraded = True
            if not self.opened.done():
                self.opened.set_result(None)
        while len(buf) >= 2:
            b0, b1 = buf[0], buf[1]
            length = b1 & 0x7F
            pos = 2
            if length == 126:
                if len(buf) < 4:
                    return
                length = int.from_bytes(buf[2:4], "big")
                pos = 4
            elif length == 127:
                if len(buf) < 10:
                    return
                length = int.from_bytes(buf[2:10], "big")
                pos = 10
            if b1 & 0x80:  # a server never masks; skip the key if one does
                pos += 4
            if len(buf) < pos + length:
                return
            payload = bytes(buf[pos : pos + length])
            del buf[: pos + length]
            opcode = b0 & 0x0F
            if opcode == 0x1:
                self._message(payload)
            elif opcode == 0x8:
                if self.transport is not None and not self.closed:
                    self.transport.write(control_frame(0x8, payload[:2]))
                    self.transport.close()
                self._lost(ConnectionError(f"closed by the server: {payload[:2].hex()}"))
                return
            elif opcode == 0x9 and self.transport is not None:
                self.transport.write(control_frame(0xA, payload[:125]))

    # -- for the subclass ----------------------------------------------------------------

    def _message(self, payload: bytes) -> None:
        """A text frame from the server."""

    def _lost(self, exc: Exception) -> None:
        """The socket ended: refused, closed by the server, or the connection lost. A
        subclass that extends it calls it first."""
        if not self.opened.done():
            self.opened.set_exception(exc)

    def close(self) -> None:
        if self.transport is not None and not self.closed:
            self.closed = True
            with contextlib.suppress(Exception):
                self.transport.write(control_frame(0x8, (1000).to_bytes(2, "big")))
            self.transport.close()
