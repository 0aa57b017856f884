"""A WebSocket client driven by hand from the calling thread, for the one-hop latency rows.

The Mosquitto row's paho clients are pumped with ``select`` from one thread
(:class:`bench._mosquitto.MqttPump`): no event loop and no loop thread sits
between the socket and the stopwatch. This is the same for a WebSocket: the
``websockets`` sans-I/O client protocol over a blocking socket with
``TCP_NODELAY``, so the fleet and bare-relay rows time the server, not an
asyncio client's wake-ups (about 45 µs per hop on the bench machine, a
third of the hop).
"""

from __future__ import annotations

import json
import socket
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from websockets.client import ClientProtocol
from websockets.frames import Frame, Opcode
from websockets.http11 import Response
from websockets.uri import parse_uri

READ_BYTES = 1 << 18


class HandWs:
    """One client connection; ``send`` writes at once, ``recv`` blocks on the socket."""

    def __init__(self, url: str, token: str | None = None, timeout_s: float = 30.0) -> None:
        uri = parse_uri(url)
        self.sock = socket.create_connection((uri.host, uri.port), timeout=timeout_s)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.protocol = ClientProtocol(uri, max_size=4 * 1024 * 1024)
        self.frames: deque[Frame] = deque()
        request = self.protocol.connect()
        if token:
            request.headers["Authorization"] = f"Bearer {token}"
        self.protocol.send_request(request)
        self._flush()
        while True:
            self._read()
            events = self.protocol.events_received()
            if events:
                break
        response = events[0]
        if not isinstance(response, Response) or response.status_code != 101:
            self.close()
            raise ConnectionError(f"{url}: handshake refused: {response!r}")
        self.frames.extend(e for e in events[1:] if isinstance(e, Frame))

    def _flush(self) -> None:
        for data in self.protocol.data_to_send():
            if data:
                self.sock.sendall(data)

    def _read(self) -> None:
        data = self.sock.recv(READ_BYTES)
        if data:
            self.protocol.receive_data(data)
        else:
            self.protocol.receive_eof()
            raise ConnectionError("the server closed the connection")
        self._flush()

    def send(self, text: str) -> None:
        self.protocol.send_text(text.encode())
        self._flush()

    def recv(self) -> str | bytes:
        """The next text or binary message (control frames are answered by the protocol)."""
        while True:
            while not self.frames:
                self._read()
                self.frames.extend(
                    e for e in self.protocol.events_received() if isinstance(e, Frame)
                )
            frame = self.frames.popleft()
            if frame.opcode is Opcode.TEXT:
                return frame.data.decode()
            if frame.opcode is Opcode.BINARY:
                return bytes(frame.data)
            if frame.opcode is Opcode.CLOSE:
                raise ConnectionError("the server closed the connection")

    def call(self, op: str, op_id: str, **fields: Any) -> dict[str, Any]:
        """Send an op with an id and read until its ack (other frames skipped)."""
        self.send(json.dumps({"op": op, "id": op_id, **fields}))
        while True:
            got = self.recv()
            if isinstance(got, str):
                answer: dict[str, Any] = json.loads(got)
                if answer.get("op") == "ack" and answer.get("id") == op_id:
                    return answer

    def next_event(self) -> str:
        """The next ``event`` push; ``routes`` and the like skipped, ``lagging``/``error`` raise."""
        while True:
            got = self.recv()
            if isinstance(got, str):
                if got.startswith('{"op":"event"'):
                    return got
                if got.startswith(('{"op":"lagging"', '{"op":"error"')):
                    raise RuntimeError(f"unexpected frame: {got[:200]!r}")

    def close(self) -> None:
        try:
            self.protocol.send_close()
            self._flush()
        except OSError:
            pass
        self.sock.close()


def time_hops_sync(
    send: Callable[[str], None], arrival: Callable[[], Any], frame: str, count: int, warmup: int
) -> list[int]:
    """One message in flight: ns from before each ``send`` to its ``arrival``, warm-up dropped."""
    samples: list[int] = []
    for _ in range(warmup + count):
        t0 = time.perf_counter_ns()
        send(frame)
        arrival()
        samples.append(time.perf_counter_ns() - t0)
    return samples[warmup:]
