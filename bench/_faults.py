"""A loopback TCP proxy that makes a link bad on purpose: a one-way delay on every byte
(a WAN's round trip), and, when told, every connection dropped, the link stalled (bytes
held, connections left open) or new connections refused.

The chaos runs put an agent behind it; the benches use its delay to replay a WAN. It
runs its own asyncio loop on a thread, so a synchronous caller steers it.

    with FaultProxy(upstream_port, delay_s=0.0145) as proxy:   # a 29 ms round trip
        ... connect to proxy.port ...
        proxy.drop()                 # every open connection reset
        proxy.stall(True)            # bytes held until stall(False)
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

T = TypeVar("T")
CHUNK = 64 * 1024
#: Timers wake up to a couple of milliseconds late: sleep until this much before a
#: chunk is due, then yield until it is.
EARLY_S = 0.002


@dataclass
class ProxyStats:
    connections: int = 0
    dropped: int = 0
    refused: int = 0
    bytes_up: int = 0  # client -> upstream
    bytes_down: int = 0  # upstream -> client


class _Pipe:
    """One direction of one connection: read, stamp, wait out the delay (and any stall),
    write, in order."""

    def __init__(
        self,
        proxy: FaultProxy,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        up: bool,
    ) -> None:
        self.proxy, self.reader, self.writer, self.up = proxy, reader, writer, up
        self.queue: asyncio.Queue[tuple[float, bytes]] = asyncio.Queue()

    async def read(self) -> None:
        try:
            while data := await self.reader.read(CHUNK):
                await self.queue.put((time.monotonic(), data))
        except (ConnectionError, OSError):
            pass
        await self.queue.put((time.monotonic(), b""))

    async def write(self) -> None:
        proxy = self.proxy
        try:
            while True:
                stamped, data = await self.queue.get()
                due = stamped + proxy.delay_s
                if due - time.monotonic() > EARLY_S:
                    await asyncio.sleep(due - time.monotonic() - EARLY_S)
                while time.monotonic() < due:  # noqa: ASYNC110 (timers wake late: spin the rest)
                    await asyncio.sleep(0)
                await proxy._flowing.wait()
                if not data:
                    if self.writer.can_write_eof():
                        self.writer.write_eof()
                    return
                self.writer.write(data)
                await self.writer.drain()
                if self.up:
                    proxy.stats.bytes_up += len(data)
                else:
                    proxy.stats.bytes_down += len(data)
        except (ConnectionError, OSError):
            pass


class FaultProxy:
    def __init__(self, upstream_port: int, delay_s: float = 0.0, host: str = "127.0.0.1") -> None:
        self.upstream = (host, upstream_port)
        self.delay_s = delay_s
        self.stats = ProxyStats()
        self.port = 0
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True)
        self._server: asyncio.Server | None = None
        self._conns: set[tuple[asyncio.StreamWriter, asyncio.StreamWriter]] = set()
        self._flowing = asyncio.Event()
        self._refusing = False

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    # -- steering (from any thread) ------------------------------------------------------
    def start(self) -> FaultProxy:
        self._thread.start()
        self._call(self._listen)
        return self

    def stop(self) -> None:
        with contextlib.suppress(RuntimeError):
            self._call(self._close)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=5)

    def set_delay(self, one_way_s: float) -> None:
        self.delay_s = one_way_s

    def drop(self) -> int:
        """Reset every open connection (RST, no FIN): how many there were."""
        return self._call(self._drop)

    def stall(self, on: bool) -> None:
        """Hold every byte (connections stay open) until ``stall(False)``."""
        self._call(self._set_flowing, not on)

    def refuse(self, on: bool) -> None:
        """Close new connections at once while on (a link that is down)."""
        self._refusing = on

    def open_connections(self) -> int:
        return len(self._conns)

    def __enter__(self) -> FaultProxy:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- on the loop ---------------------------------------------------------------------
    def _call(self, fn: Callable[..., Any], *args: Any) -> Any:
        async def run() -> Any:
            result = fn(*args)
            if asyncio.iscoroutine(result):
                result = await result
            return result

        return asyncio.run_coroutine_threadsafe(run(), self._loop).result(timeout=10)

    async def _listen(self) -> None:
        self._flowing.set()
        self._server = await asyncio.start_server(self._serve, "127.0.0.1", 0)
        self.port = self._server.sockets[0].getsockname()[1]

    async def _close(self) -> None:
        self._drop()
        if self._server is not None:
            self._server.close()
        tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)

    def _set_flowing(self, flowing: bool) -> None:
        if flowing:
            self._flowing.set()
        else:
            self._flowing.clear()

    def _drop(self) -> int:
        n = len(self._conns)
        for pair in list(self._conns):
            for writer in pair:
                _reset(writer)
        self._conns.clear()
        self.stats.dropped += n
        return n

    async def _serve(self, c_reader: asyncio.StreamReader, c_writer: asyncio.StreamWriter) -> None:
        if self._refusing:
            self.stats.refused += 1
            _reset(c_writer)
            return
        try:
            u_reader, u_writer = await asyncio.open_connection(*self.upstream)
        except OSError:
            self.stats.refused += 1
            _reset(c_writer)
            return
        self.stats.connections += 1
        pair = (c_writer, u_writer)
        self._conns.add(pair)
        up, down = _Pipe(self, c_reader, u_writer, True), _Pipe(self, u_reader, c_writer, False)
        try:
            await asyncio.gather(up.read(), up.write(), down.read(), down.write())
        finally:
            self._conns.discard(pair)
            for writer in pair:
                writer.close()


def _reset(writer: asyncio.StreamWriter) -> None:
    """Close with RST: linger on, timeout 0 (what a link cut in the middle looks like)."""
    sock = writer.get_extra_info("socket")
    if sock is not None:
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    writer.transport.abort()
