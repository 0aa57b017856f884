"""The capacity load: vehicles at 1 Hz over ``/ws/vehicle``, from several worker processes.

:class:`ProcessLoadGenerator` starts ``procs`` worker processes (``multiprocessing``,
spawn), pinned to the cores given (the bench's, not the server's). Each worker runs
its own event loop (uvloop) and owns a share of the vehicles, one TCP connection and
WebSocket each: it opens them (``start_instance`` on each), then sends each vehicle's
``update_param`` (one sample, an ``id``) once a second, spread over 100 slots of 10 ms,
one op in flight per vehicle (a vehicle still waiting for its ack skips its turn:
``late``), and times each ack. The parent asks for a window's figures over a pipe:
latencies and counters since the last window; it reads the workers' CPU by psutil.

Each vehicle's socket is a minimal WebSocket client on an ``asyncio.Protocol``
(RFC 6455: the HTTP upgrade, text frames masked with a zero key, which XORs to
the payload itself and costs the server the same unmasking as any other key;
close and ping answered). The ``websockets`` client costs several times as much
CPU a message, and 10,000 vehicles of it filled the bench's core before the
server's: the figures were the generator's. The server sees the same bytes on
the wire either way but the mask.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import multiprocessing
import os
import socket
import threading
import time
from collections.abc import Sequence
from datetime import UTC, datetime
from multiprocessing.connection import Connection
from typing import Any, cast

import orjson
import psutil

from bench._live.world import CAPS
from bench._proc import raise_nofile

SLOTS = 100
#: Sockets a worker opens at once, and how long it may take to open its share.
CONNECT_PARALLEL = 64
CONNECT_WITHIN_S = 600


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


class VehicleConn(asyncio.Protocol):
    """One vehicle's WebSocket: the handshake, frames parsed, its one op in flight timed."""

    def __init__(self, gen: WorkerGen, host: str, port: int, token: str) -> None:
        self.gen = gen
        self.request = (
            f"GET /ws/vehicle HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
            "Connection: Upgrade\r\n"
            f"Sec-WebSocket-Key: {base64.b64encode(os.urandom(16)).decode()}\r\n"
            f"Sec-WebSocket-Version: 13\r\nAuthorization: Bearer {token}\r\n\r\n"
        ).encode()
        self.transport: asyncio.Transport | None = None
        self.buf = bytearray()
        self.upgraded = False
        self.opened: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self.waiter: asyncio.Future[dict[str, Any]] | None = None
        self.waiting_for: str | None = None
        self.pending: str | None = None  # the load's op in flight
        self.t0 = 0
        self.closed = False
        self.instance_id = ""
        self.seq = 0
        self.vehicle_id = ""

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

    # -- the vehicle -------------------------------------------------------------------------

    def _lost(self, exc: Exception) -> None:
        if not self.opened.done():
            self.opened.set_exception(exc)
        if self.waiter is not None and not self.waiter.done():
            self.waiter.set_exception(exc)
        if not self.closed:
            self.closed = True
            self.gen.lost(self)

    def _message(self, payload: bytes) -> None:
        now = time.perf_counter_ns()
        if not payload.startswith(b'{"op":"ack"'):
            return
        msg = orjson.loads(payload)
        op_id = msg.get("id")
        if op_id is not None and op_id == self.pending:
            self.pending = None
            if msg.get("ok"):
                self.gen.acked += 1
                self.gen.latencies.append(now - self.t0)
            else:
                self.gen.nacks += 1
        elif self.waiter is not None and op_id == self.waiting_for and not self.waiter.done():
            self.waiter.set_result(msg)

    async def call(self, op: str, op_id: str, **fields: Any) -> dict[str, Any]:
        assert self.transport is not None
        self.waiter = asyncio.get_running_loop().create_future()
        self.waiting_for = op_id
        self.transport.write(text_frame(orjson.dumps({"op": op, "id": op_id, **fields})))
        async with asyncio.timeout(30):
            return await self.waiter

    def close(self) -> None:
        if self.transport is not None and not self.closed:
            self.closed = True
            with contextlib.suppress(Exception):
                self.transport.write(control_frame(0x8, (1000).to_bytes(2, "big")))
            self.transport.close()


class WorkerGen:
    """One worker's vehicles, its ticker and its counters."""

    def __init__(self, host: str, port: int) -> None:
        self.host, self.port = host, port
        self.vehicles: list[VehicleConn] = []
        self.latencies: list[int] = []
        self.sent = self.acked = self.nacks = self.late = self.closed = 0
        self.tick_lag_ms: list[float] = []
        self.stopping = False

    def lost(self, conn: VehicleConn) -> None:
        if not self.stopping and conn.upgraded:
            self.closed += 1

    async def connect(self, pairs: Sequence[tuple[str, str]]) -> int:
        """Open and ``start_instance`` each vehicle; the failures."""
        loop = asyncio.get_running_loop()
        failures = 0
        queue = iter(pairs)
        added: list[VehicleConn] = []

        async def one(vid: str, token: str) -> VehicleConn:
            _, conn = await loop.create_connection(
                lambda: VehicleConn(self, self.host, self.port, token), self.host, self.port
            )
            async with asyncio.timeout(60):
                await conn.opened
            ack = await conn.call(
                "start_instance", "s", vehicle_id=vid, name=vid, vehicle_type="usv",
                capabilities=CAPS,
            )  # fmt: skip
            if not ack.get("ok"):
                conn.close()
                raise ConnectionError(f"start_instance {vid}: {ack}")
            conn.vehicle_id, conn.instance_id = vid, ack["instance_id"]
            conn.seq = int(ack["last_seq"])
            return conn

        async def worker() -> None:
            nonlocal failures
            for vid, token in queue:
                try:
                    added.append(await one(vid, token))
                except (OSError, TimeoutError, ConnectionError):
                    failures += 1

        try:
            async with asyncio.timeout(CONNECT_WITHIN_S):
                await asyncio.gather(*(worker() for _ in range(CONNECT_PARALLEL)))
        except TimeoutError:  # a server that cannot take more: the rest count as failures
            failures = len(pairs) - len(added)
        self.vehicles.extend(added)
        return failures

    async def tick(self) -> None:
        loop = asyncio.get_running_loop()
        started = loop.time()
        slot = 0
        while not self.stopping:
            due = started + slot / SLOTS
            delay = due - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            else:
                self.tick_lag_ms.append(-delay * 1000)
                await asyncio.sleep(0)
            ts = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"
            vehicles = self.vehicles
            for index in range(slot % SLOTS, len(vehicles), SLOTS):
                conn = vehicles[index]
                if conn.closed or conn.transport is None:
                    continue
                if conn.pending is not None:
                    self.late += 1
                    continue
                conn.seq += 1
                op_id = str(conn.seq)
                frame = (
                    f'{{"op":"update_param","id":"{op_id}","instance_id":"{conn.instance_id}",'
                    f'"samples":[{{"seq":{conn.seq},"ts":"{ts}","lat":{43.9 + index * 1e-5:.6f},'
                    f'"lon":15.4}}]}}'
                ).encode()
                conn.pending = op_id
                conn.t0 = time.perf_counter_ns()
                conn.transport.write(text_frame(frame))
                self.sent += 1
            slot += 1

    def take_window(self) -> dict[str, Any]:
        latencies, self.latencies = self.latencies, []
        lags, self.tick_lag_ms = self.tick_lag_ms, []
        out = {"latencies": latencies, "sent": self.sent, "acked": self.acked,
               "nacks": self.nacks, "late": self.late, "closed": self.closed,
               "max_tick_lag_ms": max(lags, default=0.0)}  # fmt: skip
        self.sent = self.acked = self.nacks = self.late = 0
        return out


def worker_main(conn: Connection, host: str, port: int, cores: Sequence[int] | None) -> None:
    """A worker process: pinned, open files raised, its own loop answering the parent."""
    raise_nofile()
    if cores:
        os.sched_setaffinity(0, set(cores))
    try:
        import uvloop

        loop: asyncio.AbstractEventLoop = uvloop.new_event_loop()
    except ImportError:
        loop = asyncio.new_event_loop()
    asyncio.set_event_loop(loop)
    loop.run_until_complete(_serve(conn, host, port))
    loop.close()


async def _serve(conn: Connection, host: str, port: int) -> None:
    loop = asyncio.get_running_loop()
    gen = WorkerGen(host, port)
    ticker = asyncio.create_task(gen.tick())
    inbox: asyncio.Queue[Any] = asyncio.Queue()

    def read_pipe() -> None:  # a thread: the pipe stays blocking (an add_reader'd fd would not)
        while True:
            try:
                command = conn.recv()
            except (EOFError, OSError):
                command = ("stop",)
            loop.call_soon_threadsafe(inbox.put_nowait, command)
            if command[0] == "stop":
                return

    threading.Thread(target=read_pipe, name="pipe", daemon=True).start()
    try:
        while True:
            command = await inbox.get()
            kind = command[0]
            if kind == "add":
                failures = await gen.connect(command[1])
                conn.send(("added", len(gen.vehicles), failures))
            elif kind == "window":
                conn.send(gen.take_window())
            elif kind == "stop":
                break
    finally:
        gen.stopping = True
        ticker.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await ticker
        for vehicle in gen.vehicles:
            vehicle.close()
        await asyncio.sleep(0.5)
        conn.send(("stopped", len(gen.vehicles)))


class ProcessLoadGenerator:
    """The parent's side: workers started, vehicles shared out, windows gathered."""

    def __init__(self, ws_base: str, procs: int, cores: Sequence[int] | None) -> None:
        host_port = ws_base.split("://", 1)[1].rstrip("/")
        host, _, port = host_port.rpartition(":")
        ctx = multiprocessing.get_context("spawn")
        self.procs = []
        self.pipes: list[Connection] = []
        for _ in range(max(1, procs)):
            parent, child = ctx.Pipe()
            proc = ctx.Process(
                target=worker_main, args=(child, host, int(port), list(cores or [])), daemon=True
            )
            proc.start()
            child.close()
            self.procs.append(proc)
            self.pipes.append(parent)
        self.ps = [psutil.Process(p.pid) for p in self.procs if p.pid is not None]
        self.counts = [0] * len(self.pipes)
        self._next = 0  # the worker that gets the next vehicle

    async def _ask_all(self, messages: Sequence[Any]) -> list[Any]:
        for pipe, message in zip(self.pipes, messages, strict=True):
            if message is not None:
                pipe.send(message)
        answers = []
        for pipe, message in zip(self.pipes, messages, strict=True):
            answers.append(None if message is None else await asyncio.to_thread(pipe.recv))
        return answers

    async def add(self, pairs: Sequence[tuple[str, str]]) -> int:
        """Share the vehicles out (round robin) and open them; the failures."""
        shares: list[list[tuple[str, str]]] = [[] for _ in self.pipes]
        for pair in pairs:
            shares[self._next].append(pair)
            self._next = (self._next + 1) % len(self.pipes)
        answers = await self._ask_all([("add", s) if s else None for s in shares])
        failures = 0
        for i, answer in enumerate(answers):
            if answer is not None:  # ("added", vehicles the worker holds in all, failures)
                self.counts[i] = answer[1]
                failures += answer[2]
        return failures

    @property
    def count(self) -> int:
        """The vehicles connected, all workers together."""
        return sum(self.counts)

    async def take_window(self) -> dict[str, Any]:
        answers = await self._ask_all([("window",)] * len(self.pipes))
        out: dict[str, Any] = {"latencies": [], "sent": 0, "acked": 0, "nacks": 0, "late": 0,
                               "closed": 0, "max_tick_lag_ms": 0.0}  # fmt: skip
        for a in answers:
            out["latencies"].extend(a["latencies"])
            for key in ("sent", "acked", "nacks", "late", "closed"):
                out[key] += a[key]
            out["max_tick_lag_ms"] = max(out["max_tick_lag_ms"], a["max_tick_lag_ms"])
        return out

    def cpu_s(self) -> float:
        """The workers' CPU seconds (user + system) so far."""
        total = 0.0
        for p in self.ps:
            with contextlib.suppress(psutil.Error):
                t = p.cpu_times()
                total += t.user + t.system
        return total

    async def stop(self) -> None:
        for pipe in self.pipes:
            with contextlib.suppress(OSError):
                pipe.send(("stop",))
        for pipe in self.pipes:
            with contextlib.suppress(EOFError, OSError):
                if await asyncio.to_thread(pipe.poll, 10):
                    pipe.recv()
        for proc in self.procs:
            proc.join(5)
            if proc.is_alive():
                proc.kill()
                proc.join()
