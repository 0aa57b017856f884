"""One worker process of the capacity load: its share of the vehicles, its ticker, its counters.

A worker runs its own event loop (uvloop) and owns a share of the vehicles,
one TCP connection and WebSocket each (:class:`bench._live.rawws.RawWebSocket`):
it opens them (``start_instance`` on each), then sends each vehicle's
``update_param`` (one sample, an ``id``) once a second, spread over 100 slots
of 10 ms, one op in flight per vehicle (a vehicle still waiting for its ack
skips its turn: ``late``), and times each ack. It answers the parent
(:mod:`bench._live.loadgen`) over a pipe: ``add`` (open these vehicles),
``window`` (latencies and counters since the last window) and ``stop``.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import threading
import time
from collections.abc import Sequence
from datetime import UTC, datetime
from multiprocessing.connection import Connection
from typing import Any

import orjson

from bench._live.rawws import RawWebSocket, text_frame
from bench._live.world import CAPS
from bench._proc import raise_nofile

SLOTS = 100
#: Sockets a worker opens at once, and how long it may take to open its share.
CONNECT_PARALLEL = 64
CONNECT_WITHIN_S = 600


class VehicleConn(RawWebSocket):
    """One vehicle's WebSocket: its one op in flight timed."""

    def __init__(self, gen: WorkerGen, host: str, port: int, token: str) -> None:
        self.gen = gen
        super().__init__(host, port, "/ws/vehicle", token)
        self.waiter: asyncio.Future[dict[str, Any]] | None = None
        self.waiting_for: str | None = None
        self.pending: str | None = None  # the load's op in flight
        self.t0 = 0
        self.instance_id = ""
        self.seq = 0
        self.vehicle_id = ""

    def _lost(self, exc: Exception) -> None:
        super()._lost(exc)
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
