"""Issue 3: the live path over WebSocket, side by side with Mosquitto, in one run.

Starts a real ``fleet-server`` (``python -m server.cli``: uvicorn, uvloop,
permessage-deflate off, the embedded store in a temporary directory, rate
limits raised for the bench) as a subprocess pinned to core 0, and Mosquitto
brokers (QoS 0, ``set_tcp_nodelay``) on free loopback ports, pinned to core 0
too; the bench itself (every client, the load generator) runs in this one
asyncio process (uvloop) pinned to core 1. Sections:

1. **pub-sub**: one-hop latency for 100 B and 64 KiB (a publisher on
   ``/ws/client`` publishing to ``user/<name>/x``, a subscriber on another
   ``/ws/client`` connection; one message in flight) against Mosquitto QoS 0
   (``bench.pubsub_mqtt.mqtt_one_hop``), and throughput one publisher to one
   subscriber (100 B, at most ``WINDOW`` messages in flight, none lost).
2. **command**: ``POST /client/submit_control`` until the ``command`` push is
   read on the vehicle's ``/ws/vehicle`` socket, with 1, 100 and 1,000
   vehicles connected (each ``start_instance``'d on its socket); the
   operator holds a lease granted by the admin; the vehicle acks each one.
3. **capacity**: vehicles at 1 Hz telemetry over ``/ws/vehicle``
   (``update_param`` with one sample and an ``id``; ack latency), ramping up;
   server CPU (% of one core) and RSS by psutil, the load generator's CPU,
   errors, and which side bounds it.
4. **three-layer**: unit -> gateway -> cloud -> operator (an in-bench
   gateway relay: a local WebSocket server the unit connects to, forwarding
   over one gateway ``/ws/vehicle`` connection as ``publish`` with
   ``vehicle_id``) against two bridged Mosquitto brokers.

Each figure is min / median / max over ``--runs`` runs (batches on the same
connections). Every loop is bounded in count and time; everything runs on
127.0.0.1; every process started here is stopped at the end.

    python -m bench.live_ws [--quick] [--runs 3] [--sections pubsub,command,capacity,layers]
                            [--levels 1000,2500,5000] [--json out.json]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import gc
import json
import os
import platform
import resource
import select
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Awaitable, Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import httpx
import paho.mqtt.client as mqtt
import psutil
import websockets
from websockets.asyncio.client import ClientConnection
from websockets.asyncio.server import ServerConnection

from bench import Metric
from bench.pubsub_mqtt import LatencyResult, mqtt_one_hop

TITLE = "live path over WebSocket vs Mosquitto: pub-sub, commands, 1 Hz capacity, three layers"
ROOT = Path(__file__).resolve().parents[1]
ADMIN = "fct_bench-live-admin-0123456789abcdef"
SIZES = (100, 64 * 1024)
WINDOW = 200  # throughput: messages in flight at most
#: A capacity level is held when acks/s reach this share of the vehicles (1 Hz each)
#: with the goal's median ack latency and no errors.
HELD_FRACTION = 0.95
SERVER_CORE, BENCH_CORE = 0, 1
SERVER_CMD = [sys.executable, "-m", "server.cli"]
GOALS = {
    "pubsub_median_ratio": 1.25,
    "pubsub_p99_ratio": 1.5,
    "command_median_ms": 3.0,
    "command_p99_ms": 15.0,
    "capacity_vehicles": 5000,
    "capacity_cpu_pct": 100.0,
    "capacity_rss_mb": 600.0,
    "capacity_ack_median_ms": 20.0,
}
#: The server's settings for the bench: rate limits out of the way, presence
#: thresholds long so that idle vehicles do not churn ``fleet`` events.
SERVER_ENV = {
    "FLEET_HOST": "127.0.0.1",
    "FLEET_ADMIN_TOKEN": ADMIN,
    "FLEET_RATE_LIMIT_PER_S": "1000000",
    "FLEET_RATE_LIMIT_BURST": "1000000",
    "FLEET_WS_OPS_PER_S": "1000000",
    "FLEET_STALE_AFTER_S": "600",
    "FLEET_OFFLINE_AFTER_S": "1200",
    "FLEET_LOG_LEVEL": "warning",
}


# ---- processes ---------------------------------------------------------------------


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def raise_nofile() -> int:
    """Raise the soft limit of open files to the hard limit; the new soft limit."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < hard:
        resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
    return resource.getrlimit(resource.RLIMIT_NOFILE)[0]


def pinning() -> bool:
    return len(os.sched_getaffinity(0)) >= 2 and (os.cpu_count() or 1) >= 2


def _child_setup(core: int | None) -> Callable[[], None]:
    def setup() -> None:
        raise_nofile()
        if core is not None:
            os.sched_setaffinity(0, {core})

    return setup


def _wait_for_port(port: int, process: subprocess.Popen[bytes], what: str, within_s: float) -> None:
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"{what} exited with {process.returncode}")
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 0.2):
            return
        time.sleep(0.05)
    raise RuntimeError(f"{what} did not listen on {port} within {within_s}s")


def _stop(process: subprocess.Popen[bytes], sig: int = signal.SIGTERM) -> None:
    if process.poll() is None:
        process.send_signal(sig)
        try:
            process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


@dataclass
class ServerHandle:
    base: str
    port: int
    pid: int

    @property
    def ws(self) -> str:
        return self.base.replace("http://", "ws://")


@contextlib.contextmanager
def fleet_server(workdir: Path, core: int | None) -> Iterator[ServerHandle]:
    """``python -m server.cli`` on a free loopback port (its output in ``workdir``)."""
    port = free_port()
    env = {
        **os.environ,
        **SERVER_ENV,
        "FLEET_PORT": str(port),
        "FLEET_SNAPSHOT_PATH": str(workdir / "fleet-store.snapshot"),
    }
    env.pop("FLEET_MONGO_URL", None)
    env.pop("FLEET_REDIS_URL", None)
    log = (workdir / "server.log").open("wb")
    process = subprocess.Popen(
        SERVER_CMD,
        cwd=ROOT,
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
        preexec_fn=_child_setup(core),
    )
    try:
        _wait_for_port(port, process, "fleet-server", 60)
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(f"{base}/readyz", timeout=2).status_code == 200:
                    break
            time.sleep(0.1)
        else:
            raise RuntimeError("fleet-server did not become ready")
        yield ServerHandle(base, port, process.pid)
    finally:
        _stop(process, signal.SIGINT)
        log.close()


@contextlib.contextmanager
def mosquitto(workdir: Path, core: int | None, extra: str = "", name: str = "m") -> Iterator[int]:
    """A mosquitto broker on a free loopback port (QoS 0 set-up of pubsub_mqtt); its port."""
    binary = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
    if not Path(binary).exists():
        raise RuntimeError("mosquitto is not installed (apt-get install -y mosquitto)")
    port = free_port()
    config = workdir / f"mosquitto-{name}.conf"
    config.write_text(
        f"listener {port} 127.0.0.1\n"
        "allow_anonymous true\n"
        "persistence false\n"
        "set_tcp_nodelay true\n"
        "max_packet_size 1048576\n"
        "log_dest none\n" + extra
    )
    process = subprocess.Popen(
        [binary, "-c", str(config)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        preexec_fn=_child_setup(core),
    )
    try:
        _wait_for_port(port, process, "mosquitto", 10)
        yield port
    finally:
        _stop(process)


def mosquitto_version() -> str:
    binary = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
    with contextlib.suppress(OSError, subprocess.SubprocessError):
        out = subprocess.run([binary, "-h"], capture_output=True, text=True, timeout=5).stdout
        first = out.splitlines()[0] if out else ""
        return first.replace("mosquitto version ", "")
    return "?"


# ---- statistics --------------------------------------------------------------------


def percentile(ordered: Sequence[float], q: float) -> float:
    index = min(len(ordered) - 1, max(0, round(q * len(ordered)) - 1))
    return ordered[index]


def lat_stats(samples_ns: Sequence[int]) -> dict[str, float]:
    ordered = sorted(samples_ns)
    if not ordered:
        return {"count": 0, "median_ms": float("nan"), "p99_ms": float("nan")}
    return {
        "count": len(ordered),
        "median_ms": statistics.median(ordered) / 1e6,
        "p99_ms": percentile(ordered, 0.99) / 1e6,
        "max_ms": ordered[-1] / 1e6,
    }


def spread(values: Sequence[float]) -> tuple[float, float, float]:
    """(min, median, max) over runs."""
    return min(values), statistics.median(values), max(values)


def fmt3(values: Sequence[float], digits: int = 3) -> str:
    lo, mid, hi = spread(values)
    return f"{lo:.{digits}f} / {mid:.{digits}f} / {hi:.{digits}f}"


def verdict(ok: bool) -> str:
    return "MET" if ok else "MISSED"


# ---- clients -----------------------------------------------------------------------


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


# ---- the world: vehicles, users, a gateway -----------------------------------------


@dataclass
class World:
    server: ServerHandle
    vehicles: list[tuple[str, str]] = field(default_factory=list)  # (vehicle_id, token)
    tokens: dict[str, str] = field(default_factory=dict)
    gateway_vehicle: str = "bench-gw-unit"
    setup_s: float = 0.0


async def create_vehicles(world: World, total: int, parallel: int = 32) -> float:
    """Register vehicles (admin, concurrently) until the world has ``total``; seconds taken."""
    started = time.perf_counter()
    ids = [f"bv-{i:05d}" for i in range(len(world.vehicles), total)]
    results: dict[str, str] = {}
    queue = iter(ids)

    async def worker() -> None:
        http = await RawHttp(world.server.port, ADMIN).open()
        try:
            for vid in queue:
                body = {"vehicle_id": vid, "name": vid, "vehicle_type": "usv"}
                status, answer = await http.request("POST", "/api/vehicles", body)
                if status != 201:
                    raise RuntimeError(f"creating {vid}: {status} {answer}")
                results[vid] = answer["token"]
        finally:
            await http.close()

    async with asyncio.timeout(900):
        await asyncio.gather(*(worker() for _ in range(parallel)))
    world.vehicles.extend((vid, results[vid]) for vid in ids)
    return time.perf_counter() - started


async def build_world(server: ServerHandle, n_vehicles: int) -> World:
    world = World(server)
    started = time.perf_counter()
    await create_vehicles(world, n_vehicles)
    ids = [vid for vid, _ in world.vehicles]
    admin = await RawHttp(server.port, ADMIN).open()
    try:
        gv = world.gateway_vehicle
        status, answer = await admin.request(
            "POST", "/api/vehicles", {"vehicle_id": gv, "name": gv, "vehicle_type": "usv"}
        )
        assert status == 201, answer
        status, answer = await admin.request(
            "POST", "/api/gateways", {"gateway_id": "bench-gw", "vehicles": [gv]}
        )
        assert status == 201, answer
        world.tokens["gateway"] = answer["token"]
        users = {
            "pub": ("bench-pub", "viewer", []),
            "sub": ("bench-sub", "viewer", []),
            "op": ("bench-op", "operator", [ids[0], gv] if ids else [gv]),
        }
        for key, (name, role, vehicles) in users.items():
            status, answer = await admin.request(
                "POST", "/api/users", {"username": name, "role": role, "vehicles": vehicles}
            )
            assert status == 201, answer
            world.tokens[key] = answer["token"]
    finally:
        await admin.close()
    world.setup_s = time.perf_counter() - started
    return world


CAPS = ["stop", "go_to", "keep_station", "follow_path"]


@dataclass
class VehicleSocket:
    vehicle_id: str
    ws: ClientConnection
    instance_id: str
    seq: int


async def connect_vehicles(
    world: World, pairs: Sequence[tuple[str, str]], parallel: int = 64
) -> tuple[list[VehicleSocket], int]:
    """Connect and ``start_instance`` each vehicle; (sockets in order, failures)."""
    out: dict[int, VehicleSocket] = {}
    failures = 0
    queue = iter(enumerate(pairs))

    async def worker() -> None:
        nonlocal failures
        for index, (vid, token) in queue:
            try:
                ws = await ws_connect(f"{world.server.ws}/ws/vehicle", token)
                ack = await ws_call(
                    ws, "start_instance", "s", vehicle_id=vid, name=vid,
                    vehicle_type="usv", capabilities=CAPS,
                )  # fmt: skip
                if not ack.get("ok"):
                    raise RuntimeError(f"start_instance {vid}: {ack}")
                out[index] = VehicleSocket(vid, ws, ack["instance_id"], int(ack["last_seq"]))
            except (OSError, TimeoutError, websockets.WebSocketException, RuntimeError):
                failures += 1

    async with asyncio.timeout(600):
        await asyncio.gather(*(worker() for _ in range(parallel)))
    return [out[i] for i in sorted(out)], failures


async def close_all(sockets: Sequence[ClientConnection]) -> None:
    async def one(ws: ClientConnection) -> None:
        with contextlib.suppress(Exception):
            await ws.close()

    for start in range(0, len(sockets), 500):
        await asyncio.gather(*(one(ws) for ws in sockets[start : start + 500]))


# ---- 1. pub-sub --------------------------------------------------------------------


async def fleet_one_hop(world: World, size: int, count: int, warmup: int) -> LatencyResult:
    ws = world.server.ws
    sub = await ws_connect(f"{ws}/ws/client", world.tokens["sub"])
    pub = await ws_connect(f"{ws}/ws/client", world.tokens["pub"])
    try:
        topic = "user/bench-pub/x"
        ack = await ws_call(sub, "subscribe", "s", topics=[topic])
        assert ack["ok"], ack
        frame = json.dumps({"op": "publish", "topic": topic, "data": "x" * size})
        samples: list[int] = []
        async with asyncio.timeout(300):
            for _ in range(warmup + count):
                t0 = time.perf_counter_ns()
                await pub.send(frame)
                await next_event(sub)
                samples.append(time.perf_counter_ns() - t0)
        return LatencyResult.from_samples("fleet-ws", size, samples[warmup:])
    finally:
        await close_all([pub, sub])


async def fleet_throughput(world: World, size: int, count: int) -> dict[str, float]:
    ws = world.server.ws
    sub = await ws_connect(f"{ws}/ws/client", world.tokens["sub"])
    pub = await ws_connect(f"{ws}/ws/client", world.tokens["pub"])
    try:
        topic = "user/bench-pub/t"
        ack = await ws_call(sub, "subscribe", "s", topics=[topic])
        assert ack["ok"], ack
        frame = json.dumps({"op": "publish", "topic": topic, "data": "x" * size})
        state = {"sent": 0, "received": 0, "dropped": 0}
        room = asyncio.Event()

        async def reader() -> None:
            async for got in sub:
                if not isinstance(got, str):
                    continue
                if got.startswith('{"op":"event"'):
                    state["received"] += 1
                elif got.startswith('{"op":"lagging"'):
                    state["dropped"] += int(json.loads(got)["dropped"])
                if state["sent"] - state["received"] - state["dropped"] <= WINDOW // 2:
                    room.set()
                if state["received"] + state["dropped"] >= count:
                    return

        task = asyncio.create_task(reader())
        started = time.perf_counter()
        async with asyncio.timeout(300):
            while state["sent"] < count:
                if state["sent"] - state["received"] - state["dropped"] >= WINDOW:
                    room.clear()
                    await room.wait()
                    continue
                await pub.send(frame)
                state["sent"] += 1
            await task
        elapsed = time.perf_counter() - started
        return {
            "msgs_per_s": state["received"] / elapsed,
            "received": state["received"],
            "dropped": state["dropped"],
        }
    finally:
        await close_all([pub, sub])


class MqttPump:
    """paho clients driven from this thread with ``select`` (no loop threads)."""

    def __init__(self) -> None:
        self.clients: list[mqtt.Client] = []

    def connect(self, port: int, name: str) -> mqtt.Client:
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=name)
        done: list[bool] = []
        client.on_connect = lambda *args: done.append(True)
        client.connect("127.0.0.1", port)
        sock = client.socket()
        assert isinstance(sock, socket.socket)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.clients.append(client)
        self.until(lambda: bool(done), f"{name} could not connect to port {port}")
        return client

    def once(self, timeout: float) -> None:
        for client in self.clients:
            if client.want_write():
                client.loop_write()
        socks = {c.socket(): c for c in self.clients if c.socket() is not None}
        readable, _, _ = select.select(list(socks), [], [], timeout)  # type: ignore[type-var]
        for sock in readable:
            socks[sock].loop_read()
        for client in self.clients:
            client.loop_misc()

    def until(self, condition: Callable[[], bool], failure: str, within_s: float = 10) -> None:
        deadline = time.monotonic() + within_s
        while not condition():
            if time.monotonic() > deadline:
                raise RuntimeError(failure)
            self.once(0.05)

    def subscribe(self, client: mqtt.Client, topic: str) -> None:
        done: list[bool] = []
        client.on_subscribe = lambda *args: done.append(True)
        client.subscribe(topic, qos=0)
        self.until(lambda: bool(done), "mosquitto did not confirm the subscription")

    def close(self) -> None:
        for client in self.clients:
            with contextlib.suppress(Exception):
                client.disconnect()
                if client.want_write():
                    client.loop_write()


def mqtt_throughput(port: int, size: int, count: int) -> dict[str, float]:
    pump = MqttPump()
    try:
        sub = pump.connect(port, "bench-tp-sub")
        pub = pump.connect(port, "bench-tp-pub")
        topic = "bench/tp"
        received = [0]
        sub.on_message = lambda *args: received.__setitem__(0, received[0] + 1)
        pump.subscribe(sub, topic)
        payload = bytes(size)
        sent = 0
        started = time.perf_counter()
        deadline = time.monotonic() + 300
        while received[0] < count:
            if time.monotonic() > deadline:
                raise RuntimeError("mosquitto throughput: timed out")
            while sent < count and sent - received[0] < WINDOW:
                pub.publish(topic, payload, qos=0)
                sent += 1
            pump.once(0.05)
        elapsed = time.perf_counter() - started
        return {"msgs_per_s": received[0] / elapsed, "received": received[0], "dropped": 0}
    finally:
        pump.close()


def mqtt_chain_hop(pub_port: int, sub_port: int, size: int, count: int, warmup: int) -> list[int]:
    """One message in flight, published on one broker, received from another (bridged)."""
    pump = MqttPump()
    try:
        sub = pump.connect(sub_port, "bench-chain-sub")
        pub = pump.connect(pub_port, "bench-chain-pub")
        topic = "bench/chain/x"
        arrivals: list[int] = []
        sub.on_message = lambda *args: arrivals.append(time.perf_counter_ns())
        pump.subscribe(sub, topic)
        # The bridge connects on its own time: probe until a message crosses it.
        deadline = time.monotonic() + 20
        while not arrivals:
            if time.monotonic() > deadline:
                raise RuntimeError("the mosquitto bridge did not carry a message within 20 s")
            pub.publish(topic, b"probe", qos=0)
            with contextlib.suppress(RuntimeError):
                pump.until(lambda: bool(arrivals), "", within_s=0.2)
        for _ in range(10):  # late probes, read and forgotten
            pump.once(0.02)
        arrivals.clear()
        payload = bytes(size)
        samples: list[int] = []
        for _ in range(warmup + count):
            before = len(arrivals)
            t0 = time.perf_counter_ns()
            pub.publish(topic, payload, qos=0)
            pump.until(
                lambda before=before: len(arrivals) > before,  # type: ignore[misc]
                "a message did not cross the bridge",
            )
            samples.append(arrivals[-1] - t0)
        return samples[warmup:]
    finally:
        pump.close()


# ---- 2. command latency ------------------------------------------------------------


class PushReader:
    """Reads one vehicle socket: stamps ``command`` pushes, resolves acks by id."""

    def __init__(self, ws: ClientConnection) -> None:
        self.ws = ws
        self.command: asyncio.Future[tuple[int, dict[str, Any]]] | None = None
        self.acks: dict[str, asyncio.Future[dict[str, Any]]] = {}
        self.task = asyncio.create_task(self._run())

    async def _run(self) -> None:
        with contextlib.suppress(websockets.ConnectionClosed):
            async for frame in self.ws:
                now = time.perf_counter_ns()
                if not isinstance(frame, str):
                    continue
                msg = json.loads(frame)
                if msg.get("op") == "command":
                    if self.command is not None and not self.command.done():
                        self.command.set_result((now, msg))
                elif msg.get("op") == "ack":
                    fut = self.acks.pop(msg.get("id", ""), None)
                    if fut is not None and not fut.done():
                        fut.set_result(msg)

    async def call(self, op: str, op_id: str, **fields: Any) -> dict[str, Any]:
        fut: asyncio.Future[dict[str, Any]] = asyncio.get_running_loop().create_future()
        self.acks[op_id] = fut
        await self.ws.send(json.dumps({"op": op, "id": op_id, **fields}))
        return await asyncio.wait_for(fut, 30)


async def command_latency(
    world: World,
    levels: Sequence[int],
    runs: int,
    count: int,
    warmup: int,
    report: Callable[[str], None],
) -> list[dict[str, Any]]:
    server = world.server
    admin = await RawHttp(server.port, ADMIN).open()
    operator = await RawHttp(server.port, world.tokens["op"]).open()
    sockets: list[VehicleSocket] = []
    results: list[dict[str, Any]] = []
    reader: PushReader | None = None
    try:
        for level in levels:
            if len(sockets) < level:
                more, failures = await connect_vehicles(world, world.vehicles[len(sockets) : level])
                if failures:
                    raise RuntimeError(f"command bench: {failures} vehicles failed to connect")
                sockets.extend(more)
            measured = sockets[0]
            if reader is None:
                reader = PushReader(measured.ws)
                status, answer = await admin.request(
                    "POST",
                    "/client/grant_control",
                    {"instance_id": measured.instance_id, "user": "bench-op", "duration_s": 3600},
                )
                if status != 200:
                    raise RuntimeError(f"grant_control: {status} {answer}")
            body = {
                "instance_ids": [measured.instance_id],
                "command": {"type": "go_to", "args": {"lat": 43.95, "lon": 15.45}},
                "ttl_s": 60,
            }
            per_run: list[dict[str, float]] = []
            for run in range(runs):
                samples: list[int] = []
                async with asyncio.timeout(300):
                    for i in range(warmup + count):
                        fut: asyncio.Future[tuple[int, dict[str, Any]]]
                        fut = asyncio.get_running_loop().create_future()
                        reader.command = fut
                        t0 = time.perf_counter_ns()
                        status, answer = await operator.request(
                            "POST", "/client/submit_control", body
                        )
                        if status != 202:
                            raise RuntimeError(f"submit_control: {status} {answer}")
                        arrived, push = await fut
                        samples.append(arrived - t0)
                        ack = await reader.call(
                            "update_fbmessage",
                            f"a{level}-{run}-{i}",
                            instance_id=measured.instance_id,
                            control_mode="remote",
                            acks=[
                                {"command_id": push["command_id"], "status": "accepted"},
                                {"command_id": push["command_id"], "status": "done"},
                            ],
                        )
                        if not ack.get("ok"):
                            raise RuntimeError(f"update_fbmessage: {ack}")
                per_run.append(lat_stats(samples[warmup:]))
            results.append({"vehicles": level, "runs": per_run})
            report(
                f"  command @ {level:>5} vehicles: median {fmt3([r['median_ms'] for r in per_run])}"
                f" ms, p99 {fmt3([r['p99_ms'] for r in per_run])} ms"
            )
    finally:
        if reader is not None:
            reader.task.cancel()
        await close_all([s.ws for s in sockets])
        await admin.close()
        await operator.close()
    return results


# ---- 3. capacity -------------------------------------------------------------------


class LoadGenerator:
    """Vehicles at 1 Hz: ``update_param`` with one sample and an id; ack latency.

    One ticker task sends every 10 ms to the vehicles whose phase falls in
    that slot (vehicle i in slot i % 100), one reader task per socket.
    """

    SLOTS = 100

    def __init__(self) -> None:
        self.vehicles: list[VehicleSocket] = []
        self.pending: list[dict[str, int]] = []
        self.latencies: list[int] = []
        self.sent = 0
        self.acked = 0
        self.nacks = 0
        self.closed = 0
        self.late = 0  # sends skipped because the previous one was still unanswered
        self.tick_lag_ms: list[float] = []
        self._readers: list[asyncio.Task[None]] = []
        self._ticker: asyncio.Task[None] | None = None
        self._stop = False

    def add(self, sockets: Sequence[VehicleSocket]) -> None:
        for vs in sockets:
            index = len(self.vehicles)
            self.vehicles.append(vs)
            self.pending.append({})
            self._readers.append(asyncio.create_task(self._read(index)))

    async def _read(self, index: int) -> None:
        ws = self.vehicles[index].ws
        pending = self.pending[index]
        try:
            async for frame in ws:
                now = time.perf_counter_ns()
                msg = json.loads(frame)
                if msg.get("op") == "ack":
                    t0 = pending.pop(msg.get("id"), None)
                    if t0 is None:
                        continue
                    if msg.get("ok"):
                        self.acked += 1
                        self.latencies.append(now - t0)
                    else:
                        self.nacks += 1
        except websockets.ConnectionClosed:
            pass
        if not self._stop:
            self.closed += 1

    def start(self) -> None:
        self._ticker = asyncio.create_task(self._tick())

    async def _tick(self) -> None:
        loop = asyncio.get_running_loop()
        started = loop.time()
        slot = 0
        while not self._stop:
            due = started + slot * (1 / self.SLOTS)
            delay = due - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            else:
                self.tick_lag_ms.append(-delay * 1000)
            ts = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"
            for index in range(slot % self.SLOTS, len(self.vehicles), self.SLOTS):
                vs = self.vehicles[index]
                pending = self.pending[index]
                if pending:
                    self.late += 1
                    continue
                vs.seq += 1
                op_id = str(vs.seq)
                frame = (
                    f'{{"op":"update_param","id":"{op_id}","instance_id":"{vs.instance_id}",'
                    f'"samples":[{{"seq":{vs.seq},"ts":"{ts}","lat":{43.9 + index * 1e-5:.6f},'
                    f'"lon":15.4}}]}}'
                )
                pending[op_id] = time.perf_counter_ns()
                try:
                    await vs.ws.send(frame)
                except websockets.ConnectionClosed:
                    pending.pop(op_id, None)
                    continue
                self.sent += 1
            slot += 1

    async def stop(self) -> None:
        self._stop = True
        if self._ticker is not None:
            self._ticker.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._ticker
        for task in self._readers:
            task.cancel()
        await asyncio.gather(*self._readers, return_exceptions=True)

    def take_window(self) -> dict[str, Any]:
        latencies, self.latencies = self.latencies, []
        lags, self.tick_lag_ms = self.tick_lag_ms, []
        counts: dict[str, float] = {"sent": self.sent, "acked": self.acked,
                                    "nacks": self.nacks, "closed": self.closed,
                                    "late": self.late}  # fmt: skip
        self.sent = self.acked = self.nacks = self.late = 0
        counts["max_tick_lag_ms"] = max(lags, default=0.0)
        return {"latencies": latencies, **counts}


async def capacity(
    world: World,
    levels: Sequence[int],
    runs: int,
    window_s: float,
    warmup_s: float,
    report: Callable[[str], None],
) -> list[dict[str, Any]]:
    server_proc = psutil.Process(world.server.pid)
    me = psutil.Process()
    gen = LoadGenerator()
    gen.start()
    results: list[dict[str, Any]] = []
    try:
        for position, level in enumerate(levels):
            if results and not results[-1]["held"]:
                last = results[-1]["vehicles"]
                results.extend({"vehicles": n, "skipped": True} for n in levels[position:])
                report(f"  capacity: {level} and up not attempted ({last} not held)")
                break
            create_s = 0.0
            if level > len(world.vehicles):
                create_s = await create_vehicles(world, level)
            started = time.perf_counter()
            more, failures = await connect_vehicles(
                world, world.vehicles[len(gen.vehicles) : level]
            )
            gen.add(more)
            connect_s = time.perf_counter() - started
            gc.collect()
            await asyncio.sleep(warmup_s)
            gen.take_window()
            per_run: list[dict[str, Any]] = []
            for _ in range(runs):
                s0, m0, w0 = server_proc.cpu_times(), me.cpu_times(), time.perf_counter()
                rss_max = 0
                end = w0 + window_s
                while time.perf_counter() < end:
                    await asyncio.sleep(min(1.0, max(0.0, end - time.perf_counter())))
                    rss_max = max(rss_max, server_proc.memory_info().rss)
                s1, m1, w1 = server_proc.cpu_times(), me.cpu_times(), time.perf_counter()
                window = gen.take_window()
                wall = w1 - w0
                stats = lat_stats(window.pop("latencies"))
                per_run.append(
                    {
                        **stats,
                        **window,
                        "server_cpu_pct": 100 * (s1.user + s1.system - s0.user - s0.system) / wall,
                        "loadgen_cpu_pct": 100 * (m1.user + m1.system - m0.user - m0.system) / wall,
                        "server_rss_mb": rss_max / 2**20,
                        "acks_per_s": window["acked"] / wall,
                    }
                )
            errors = failures + sum(r["nacks"] for r in per_run) + gen.closed
            result = {
                "vehicles": len(gen.vehicles),
                "target": level,
                "connect_failures": failures,
                "create_s": create_s,
                "connect_s": connect_s,
                "errors": errors,
                "runs": per_run,
            }
            # Held: nearly every vehicle answered each second, within the goal's median
            # ack latency, without errors (the ramp stops at the first level not held).
            rate = statistics.median(r["acks_per_s"] for r in per_run)
            result["held"] = (
                rate >= HELD_FRACTION * len(gen.vehicles)
                and statistics.median(r["median_ms"] for r in per_run)
                <= GOALS["capacity_ack_median_ms"]
                and errors == 0
            )
            result["bound"] = bound_by(result)
            results.append(result)
            report(
                f"  capacity @ {len(gen.vehicles):>5}: server cpu"
                f" {fmt3([r['server_cpu_pct'] for r in per_run], 0)} %,"
                f" rss {fmt3([r['server_rss_mb'] for r in per_run], 0)} MB,"
                f" ack median {fmt3([r['median_ms'] for r in per_run], 1)} ms,"
                f" p99 {fmt3([r['p99_ms'] for r in per_run], 1)} ms,"
                f" loadgen cpu {fmt3([r['loadgen_cpu_pct'] for r in per_run], 0)} %,"
                f" acks/s {fmt3([r['acks_per_s'] for r in per_run], 0)}, errors {errors}"
            )
    finally:
        await gen.stop()
        await close_all([v.ws for v in gen.vehicles])
    return results


def bound_by(result: dict[str, Any]) -> str:
    """Which side limits a level: the process whose core is (nearly) full."""
    runs = result["runs"]
    server = statistics.median(r["server_cpu_pct"] for r in runs)
    loadgen = statistics.median(r["loadgen_cpu_pct"] for r in runs)
    struggling = not result["held"]
    if loadgen >= 90:
        return "load generator (CPU)"
    if server >= 90 or (struggling and server >= 70 and server > loadgen):
        return "server (CPU)"
    if struggling:
        return "neither core saturated"
    return "neither (headroom on both cores)"


# ---- 4. three layers ---------------------------------------------------------------


async def fleet_three_layer(world: World, size: int, count: int, warmup: int) -> list[int]:
    """unit -> in-bench gateway relay -> /ws/vehicle (gateway token) -> cloud -> /ws/client."""
    server = world.server
    vid = world.gateway_vehicle
    topic = f"vehicle/{vid}/x"
    upstream = await ws_connect(f"{server.ws}/ws/vehicle", world.tokens["gateway"])
    operator = await ws_connect(f"{server.ws}/ws/client", world.tokens["op"])
    ack = await ws_call(operator, "subscribe", "s", topics=[topic])
    assert ack["ok"], ack

    async def drain_upstream() -> None:  # acks, routes pushes: read and dropped
        with contextlib.suppress(websockets.ConnectionClosed):
            async for _ in upstream:
                pass

    async def relay(conn: ServerConnection) -> None:
        """The gateway: each unit frame goes up as a publish on the unit's behalf."""
        async for frame in conn:
            msg = json.loads(frame)
            if msg.get("op") == "publish":
                msg["vehicle_id"] = vid
                await upstream.send(json.dumps(msg, separators=(",", ":")))

    drain = asyncio.create_task(drain_upstream())
    gateway = await websockets.serve(relay, "127.0.0.1", 0, compression=None, ping_interval=None)
    unit: ClientConnection | None = None
    try:
        port = next(iter(gateway.sockets)).getsockname()[1]
        unit = await ws_connect(f"ws://127.0.0.1:{port}")
        frame = json.dumps({"op": "publish", "topic": topic, "data": "x" * size})
        samples: list[int] = []
        async with asyncio.timeout(300):
            for _ in range(warmup + count):
                t0 = time.perf_counter_ns()
                await unit.send(frame)
                await next_event(operator)
                samples.append(time.perf_counter_ns() - t0)
        return samples[warmup:]
    finally:
        await close_all([ws for ws in (unit, operator, upstream) if ws is not None])
        gateway.close()
        await gateway.wait_closed()
        drain.cancel()


# ---- the run -----------------------------------------------------------------------


@dataclass
class Config:
    sections: list[str]
    runs: int
    count: int
    warmup: int
    tp_count: int
    cmd_levels: list[int]
    cmd_count: int
    cap_levels: list[int]
    cap_window_s: float
    cap_warmup_s: float
    quick: bool


def machine() -> dict[str, Any]:
    model = "?"
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    return {
        "nproc": os.cpu_count(),
        "cpu": model,
        "ram_gib": round(psutil.virtual_memory().total / 2**30, 1),
        "python": platform.python_version(),
        "mosquitto": mosquitto_version(),
        "websockets": websockets.__version__,
        "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "pinned": pinning(),
    }


def run_async(coro: Awaitable[Any]) -> Any:
    try:
        import uvloop

        with asyncio.Runner(loop_factory=uvloop.new_event_loop) as runner:
            return runner.run(coro)  # type: ignore[arg-type]
    except ImportError:
        return asyncio.run(coro)  # type: ignore[arg-type]


def run_bench(cfg: Config, report: Callable[[str], None]) -> dict[str, Any]:
    out: dict[str, Any] = {"machine": machine(), "config": asdict(cfg), "goals": GOALS}
    nofile = raise_nofile()
    pinned = pinning()
    server_core = SERVER_CORE if pinned else None
    if pinned:
        os.sched_setaffinity(0, {BENCH_CORE})
    need = max([1, *(cfg.cmd_levels if "command" in cfg.sections else [])])
    most = max([need, *(cfg.cap_levels if "capacity" in cfg.sections else [])])
    if most + 100 > nofile:
        raise RuntimeError(f"ulimit -n is {nofile}: too low for {most} vehicle sockets")
    with tempfile.TemporaryDirectory(prefix="bench-live-") as tmp:
        workdir = Path(tmp)
        with fleet_server(workdir, server_core) as server:
            world = run_async(build_world(server, need))
            report(f"  setup: {need} vehicles, users and a gateway in {world.setup_s:.1f} s")
            out["setup_s"] = world.setup_s
            out["server_rss_idle_mb"] = psutil.Process(server.pid).memory_info().rss / 2**20
            if "pubsub" in cfg.sections:
                out["pubsub"] = section_pubsub(cfg, world, workdir, server_core, report)
            if "layers" in cfg.sections:
                out["layers"] = section_layers(cfg, world, workdir, server_core, report)
            if "command" in cfg.sections:
                out["command"] = run_async(
                    command_latency(
                        world, cfg.cmd_levels, cfg.runs, cfg.cmd_count, cfg.warmup // 4, report
                    )
                )
            if "capacity" in cfg.sections:
                out["capacity"] = run_async(
                    capacity(
                        world, cfg.cap_levels, cfg.runs, cfg.cap_window_s, cfg.cap_warmup_s, report
                    )
                )
            with contextlib.suppress(OSError):
                tail = (workdir / "server.log").read_text(errors="replace").splitlines()[-5:]
                out["server_log_tail"] = tail
    return out


def section_pubsub(
    cfg: Config, world: World, workdir: Path, core: int | None, report: Callable[[str], None]
) -> dict[str, Any]:
    result: dict[str, Any] = {"latency": {}, "throughput": {}}
    with mosquitto(workdir, core, name="hop") as port:
        for size in SIZES:
            fleet_runs: list[dict[str, float]] = []
            mqtt_runs: list[dict[str, float]] = []
            for _ in range(cfg.runs):  # interleaved, so both see the same machine
                ours = run_async(fleet_one_hop(world, size, cfg.count, cfg.warmup))
                theirs = mqtt_one_hop(port, size, cfg.count, cfg.warmup)
                fleet_runs.append({"median_ms": ours.median_ms, "p99_ms": ours.p99_ms})
                mqtt_runs.append({"median_ms": theirs.median_ms, "p99_ms": theirs.p99_ms})
            result["latency"][size] = {"fleet": fleet_runs, "mosquitto": mqtt_runs}
            report(
                f"  pub-sub {size:>6} B: fleet median {fmt3([r['median_ms'] for r in fleet_runs])}"
                f" p99 {fmt3([r['p99_ms'] for r in fleet_runs])};"
                f" mosquitto median {fmt3([r['median_ms'] for r in mqtt_runs])}"
                f" p99 {fmt3([r['p99_ms'] for r in mqtt_runs])} ms"
            )
        size = SIZES[0]
        fleet_tp = []
        mqtt_tp = []
        for _ in range(cfg.runs):
            fleet_tp.append(run_async(fleet_throughput(world, size, cfg.tp_count)))
            mqtt_tp.append(mqtt_throughput(port, size, cfg.tp_count))
        result["throughput"] = {"size": size, "fleet": fleet_tp, "mosquitto": mqtt_tp}
        report(
            f"  throughput {size} B: fleet {fmt3([r['msgs_per_s'] for r in fleet_tp], 0)} msg/s,"
            f" mosquitto {fmt3([r['msgs_per_s'] for r in mqtt_tp], 0)} msg/s"
        )
    return result


BRIDGE = """
connection bench-bridge
address 127.0.0.1:{port}
topic bench/# out 0
cleansession true
try_private false
notifications false
bridge_attempt_unsubscribe false
start_type automatic
restart_timeout 1
keepalive_interval 60
"""


def section_layers(
    cfg: Config, world: World, workdir: Path, core: int | None, report: Callable[[str], None]
) -> dict[str, Any]:
    size = SIZES[0]
    fleet_runs: list[dict[str, float]] = []
    mqtt_runs: list[dict[str, float]] = []
    with (
        mosquitto(workdir, core, name="cloud") as cloud,
        mosquitto(workdir, core, BRIDGE.format(port=cloud), name="edge") as edge,
    ):
        for _ in range(cfg.runs):
            fleet_runs.append(
                lat_stats(run_async(fleet_three_layer(world, size, cfg.count, cfg.warmup)))
            )
            mqtt_runs.append(lat_stats(mqtt_chain_hop(edge, cloud, size, cfg.count, cfg.warmup)))
    report(
        f"  three layers {size} B: fleet median {fmt3([r['median_ms'] for r in fleet_runs])}"
        f" p99 {fmt3([r['p99_ms'] for r in fleet_runs])};"
        f" mosquitto bridge median {fmt3([r['median_ms'] for r in mqtt_runs])}"
        f" p99 {fmt3([r['p99_ms'] for r in mqtt_runs])} ms"
    )
    return {"size": size, "fleet": fleet_runs, "mosquitto_bridge": mqtt_runs}


# ---- the table ---------------------------------------------------------------------


def _col(runs: Sequence[dict[str, Any]], key: str, digits: int = 3) -> str:
    return fmt3([r[key] for r in runs], digits)


def _mid(runs: Sequence[dict[str, Any]], key: str) -> float:
    return statistics.median(r[key] for r in runs)


def table(out: dict[str, Any]) -> str:
    m = out["machine"]
    lines = [
        f"Issue 3 live path: fleet-server over WebSocket vs Mosquitto {m['mosquitto']}"
        f" (QoS 0), {out['config']['runs']} runs each, figures min / median / max over runs",
        f"machine: {m['nproc']} CPU ({m['cpu']}), {m['ram_gib']} GiB RAM, Python {m['python']},"
        f" websockets {m['websockets']}, {m['date']};"
        + (" server and brokers on core 0, bench on core 1" if m["pinned"] else " not pinned"),
        "",
    ]
    if "pubsub" in out:
        p = out["pubsub"]
        c = out["config"]
        lines += [
            f"1. one-hop pub-sub latency (one message in flight, {c['count']} messages"
            f" after {c['warmup']} warm-up, per run), ms",
            f"   {'size':>8}  {'path':<14} {'median':>26} {'p99':>26}",
        ]
        for size, d in p["latency"].items():
            for name, runs in (("fleet /ws", d["fleet"]), ("mosquitto", d["mosquitto"])):
                lines.append(
                    f"   {int(size):>8}  {name:<14} {_col(runs, 'median_ms'):>26}"
                    f" {_col(runs, 'p99_ms'):>26}"
                )
            rm = _mid(d["fleet"], "median_ms") / _mid(d["mosquitto"], "median_ms")
            rp = _mid(d["fleet"], "p99_ms") / _mid(d["mosquitto"], "p99_ms")
            lines.append(
                f"   {int(size):>8}  {'ratio':<14} {rm:>20.2f}x {'':>4} {rp:>20.2f}x"
                f"   goal <= {GOALS['pubsub_median_ratio']}x median"
                f" {verdict(rm <= GOALS['pubsub_median_ratio'])},"
                f" <= {GOALS['pubsub_p99_ratio']}x p99 {verdict(rp <= GOALS['pubsub_p99_ratio'])}"
            )
        t = p["throughput"]
        lines += [
            f"   throughput one publisher -> one subscriber, {t['size']} B,"
            f" <= {WINDOW} in flight, {c['tp_count']} messages: msgs/s",
            f"             {'fleet /ws':<14} {_col(t['fleet'], 'msgs_per_s', 0):>26}"
            f"  (lost: {sum(r['dropped'] for r in t['fleet'])})",
            f"             {'mosquitto':<14} {_col(t['mosquitto'], 'msgs_per_s', 0):>26}",
            "",
        ]
    if "command" in out:
        lines += [
            "2. command latency, POST /client/submit_control -> command push read on the"
            " vehicle's /ws/vehicle, ms",
            f"   {'vehicles':>8}  {'median':>26} {'p99':>26}",
        ]
        for r in out["command"]:
            lines.append(
                f"   {r['vehicles']:>8}  {_col(r['runs'], 'median_ms'):>26}"
                f" {_col(r['runs'], 'p99_ms'):>26}"
            )
        last = out["command"][-1]
        med, p99 = _mid(last["runs"], "median_ms"), _mid(last["runs"], "p99_ms")
        lines += [
            f"   at {last['vehicles']}: goal median <= {GOALS['command_median_ms']} ms"
            f" {verdict(med <= GOALS['command_median_ms'])},"
            f" p99 <= {GOALS['command_p99_ms']} ms {verdict(p99 <= GOALS['command_p99_ms'])}",
            "",
        ]
    if "capacity" in out:
        c = out["config"]
        lines += [
            f"3. capacity at 1 Hz telemetry over /ws/vehicle (update_param, one sample, ack"
            f" latency; {c['cap_window_s']:g} s windows after {c['cap_warmup_s']:g} s warm-up)",
            f"   {'vehicles':>8} {'server cpu %':>16} {'server rss MB':>16}"
            f" {'ack median ms':>20} {'ack p99 ms':>22} {'loadgen cpu %':>16}"
            f" {'acks/s':>20} {'errors':>6}  bound by",
        ]
        for r in out["capacity"]:
            if r.get("skipped"):
                lines.append(f"   {r['vehicles']:>8}  not attempted: the level below was not held")
                continue
            runs = r["runs"]
            lines.append(
                f"   {r['vehicles']:>8} {_col(runs, 'server_cpu_pct', 0):>16}"
                f" {_col(runs, 'server_rss_mb', 0):>16} {_col(runs, 'median_ms', 1):>20}"
                f" {_col(runs, 'p99_ms', 1):>22} {_col(runs, 'loadgen_cpu_pct', 0):>16}"
                f" {_col(runs, 'acks_per_s', 0):>20} {r['errors']:>6}  {r['bound']}"
                + ("" if r["held"] else "  (not held)")
            )
        measured = [r for r in out["capacity"] if not r.get("skipped")]
        held = [r for r in measured if r["held"]]
        top = held[-1] if held else measured[0]
        runs = top["runs"]
        ok = {
            "vehicles": bool(held) and top["vehicles"] >= GOALS["capacity_vehicles"],
            "cpu": max(r["server_cpu_pct"] for r in runs) < GOALS["capacity_cpu_pct"],
            "rss": max(r["server_rss_mb"] for r in runs) <= GOALS["capacity_rss_mb"],
            "median": _mid(runs, "median_ms") <= GOALS["capacity_ack_median_ms"],
            "errors": top["errors"] == 0,
        }
        lines += [
            f"   largest level held: {top['vehicles'] if held else 'none'}"
            f" (held: acks/s >= {HELD_FRACTION:.0%} of the vehicles, median ack"
            f" <= {GOALS['capacity_ack_median_ms']:g} ms, no errors)."
            f" Goal 5,000 vehicles {verdict(ok['vehicles'])}; at {top['vehicles']}:"
            f" server under one core {verdict(ok['cpu'])}, RSS <= 600 MB {verdict(ok['rss'])},"
            f" median ack <= 20 ms {verdict(ok['median'])}, no errors {verdict(ok['errors'])}",
            "",
        ]
    if "layers" in out:
        d = out["layers"]
        lines += [
            f"4. three-layer route, {d['size']} B, one in flight, ms:"
            " unit -> gateway -> cloud -> operator",
            f"   {'path':<34} {'median':>26} {'p99':>26}",
            f"   {'fleet (unit->relay->/ws/vehicle->/ws/client)':<34}",
            f"   {'':<34} {_col(d['fleet'], 'median_ms'):>26} {_col(d['fleet'], 'p99_ms'):>26}",
            f"   {'mosquitto edge -> bridge -> cloud':<34}"
            f" {_col(d['mosquitto_bridge'], 'median_ms'):>26}"
            f" {_col(d['mosquitto_bridge'], 'p99_ms'):>26}",
            "",
        ]
    return "\n".join(lines)


def metrics(out: dict[str, Any]) -> list[Metric]:
    """The figures as rows of ``python -m bench``'s table (values: one per run)."""
    rows: list[Metric] = []

    def add(name: str, unit: str, values: list[float], goal: tuple[str, float] | None = None):
        rows.append(Metric(name, unit, values, goal))

    if "pubsub" in out:
        for size, d in out["pubsub"]["latency"].items():
            f, m = d["fleet"], d["mosquitto"]
            for key, label in (("median_ms", "median"), ("p99_ms", "p99")):
                add(f"pub-sub {size} B {label}, fleet", "ms", [r[key] for r in f])
                add(f"pub-sub {size} B {label}, mosquitto", "ms", [r[key] for r in m])
            add(
                f"pub-sub {size} B median / mosquitto",
                "ratio",
                [a["median_ms"] / b["median_ms"] for a, b in zip(f, m, strict=True)],
                ("max", GOALS["pubsub_median_ratio"]),
            )
            add(
                f"pub-sub {size} B p99 / mosquitto",
                "ratio",
                [a["p99_ms"] / b["p99_ms"] for a, b in zip(f, m, strict=True)],
                ("max", GOALS["pubsub_p99_ratio"]),
            )
        t = out["pubsub"]["throughput"]
        add(f"throughput 1->1 {t['size']} B, fleet", "msg/s", [r["msgs_per_s"] for r in t["fleet"]])
        add(
            f"throughput 1->1 {t['size']} B, mosquitto",
            "msg/s",
            [r["msgs_per_s"] for r in t["mosquitto"]],
        )
    for r in out.get("command", []):
        at_goal = r["vehicles"] >= 1000
        add(
            f"command median @ {r['vehicles']} vehicles",
            "ms",
            [x["median_ms"] for x in r["runs"]],
            ("max", GOALS["command_median_ms"]) if at_goal else None,
        )
        add(
            f"command p99 @ {r['vehicles']} vehicles",
            "ms",
            [x["p99_ms"] for x in r["runs"]],
            ("max", GOALS["command_p99_ms"]) if at_goal else None,
        )
    if "capacity" in out:
        measured = [r for r in out["capacity"] if not r.get("skipped")]
        held = [r for r in measured if r["held"]]
        add(
            "capacity: vehicles held at 1 Hz",
            "vehicles",
            [float(held[-1]["vehicles"] if held else 0)],
            ("min", GOALS["capacity_vehicles"]),
        )
        for r in measured:
            n, runs = r["vehicles"], r["runs"]
            tag = "" if r["held"] else " (not held)"
            add(f"capacity @ {n}{tag}: server CPU", "% core", [x["server_cpu_pct"] for x in runs])
            add(f"capacity @ {n}{tag}: server RSS", "MB", [x["server_rss_mb"] for x in runs])
            add(f"capacity @ {n}{tag}: ack median", "ms", [x["median_ms"] for x in runs])
            add(f"capacity @ {n}{tag}: ack p99", "ms", [x["p99_ms"] for x in runs])
            add(
                f"capacity @ {n}{tag}: load gen CPU", "% core", [x["loadgen_cpu_pct"] for x in runs]
            )
    if "layers" in out:
        d = out["layers"]
        for key, label in (("median_ms", "median"), ("p99_ms", "p99")):
            add(f"three layers {d['size']} B {label}, fleet", "ms", [r[key] for r in d["fleet"]])
            add(
                f"three layers {d['size']} B {label}, mosquitto bridge",
                "ms",
                [r[key] for r in d["mosquitto_bridge"]],
            )
    return rows


def run(runs: int) -> list[Metric]:
    """``python -m bench``: the full bench (no --quick); its own table goes to stderr."""
    cfg, _ = parse_args(["--runs", str(max(3, runs))])

    def report(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    out = run_bench(cfg, report)
    print(table(out), file=sys.stderr, flush=True)
    return metrics(out)


def parse_args(argv: Sequence[str] | None) -> tuple[Config, argparse.Namespace]:
    parser = argparse.ArgumentParser(
        prog="python -m bench.live_ws", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--quick", action="store_true", help="a short run: small capacity ramp")
    parser.add_argument("--runs", type=int, default=3, help="runs per figure (at least 3)")
    parser.add_argument(
        "--sections",
        default="pubsub,command,capacity,layers",
        help="comma list of pubsub, command, capacity, layers",
    )
    parser.add_argument("--count", type=int, default=None, help="latency messages per run")
    parser.add_argument("--levels", default=None, help="capacity ramp, e.g. 1000,2500,5000")
    parser.add_argument("--window-s", type=float, default=None, help="capacity window per run")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args(argv)
    quick = args.quick
    levels = args.levels or ("100,250,1000" if quick else "250,500,1000,2500,5000")
    count = args.count or (500 if quick else 2000)
    cfg = Config(
        sections=[s.strip() for s in args.sections.split(",") if s.strip()],
        runs=max(1, args.runs),
        count=count,
        warmup=max(20, count // 10),
        tp_count=5000 if quick else 20000,
        cmd_levels=[1, 100, 1000],
        cmd_count=100 if quick else 300,
        cap_levels=[int(x) for x in levels.split(",")],
        cap_window_s=args.window_s or (4.0 if quick else 10.0),
        cap_warmup_s=3.0 if quick else 5.0,
        quick=quick,
    )
    return cfg, args


def main(argv: Sequence[str] | None = None) -> int:
    cfg, args = parse_args(argv)
    started = time.perf_counter()

    def report(line: str) -> None:
        print(f"[{time.perf_counter() - started:7.1f}s]{line}", file=sys.stderr, flush=True)

    out = run_bench(cfg, report)
    out["elapsed_s"] = time.perf_counter() - started
    print(table(out))
    print(f"(bench took {out['elapsed_s']:.0f} s)")
    if args.json:
        args.json.write_text(json.dumps(out, indent=2, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
