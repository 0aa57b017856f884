"""The soak's floods (``bench._soak``): each bound a flood can press on, pressed.

With the soak's vehicles still streaming, each bound of ``docs/security.md`` ("Limits")
that a flood can press on is pressed, one after the other:

- **send queue, frames** (``FLEET_WS_QUEUE_SIZE``, 1,000): a ``/ws/client``
  subscriber that never reads (4 KiB receive buffer), 3,000 small messages
  published to its topic; then it reads: it gets at most the queue's 1,000 frames
  plus what the two kernels' buffers held, and ``lagging`` pushes that account for
  every message it missed.
- **send queue, bytes** (``FLEET_WS_QUEUE_BYTES``, 8 MiB): the same with 400
  messages of 64 KiB (25 MiB): the subscriber is closed 4429 and its queue let go.
- **frames per second** (``FLEET_WS_OPS_PER_S``, 500): a publisher sending 2,000
  ops as fast as it can: the ones past the bucket are refused ``rate_limited``.
- **topics per socket** (``FLEET_WS_MAX_TOPICS``, 256): 300 topics subscribed on
  one socket, 60 per op: 256 taken, the rest refused ``invalid``.
- **pending control requests** (``FLEET_MAX_PENDING_REQUESTS``, 50): 60 operators
  each ask for control of one instance: 50 stand, the others 429.
- **commands waiting on one instance** (256): the lease holder submits 300
  ``keep_station`` to a vehicle that never acknowledges them: 256 queued, the rest
  429; a ``stop`` still passes.
- **an agent's outbox** (``fleet-agent run --max-samples``): ``fleet-agent`` with
  ``--max-samples 200`` at 50 Hz and no server to reach for 15 s: the outbox holds
  200 rows at most, the oldest dropped and counted.

Each flood returns its row of the soak's table: the bound, what was sent, what
came of it, and whether the bound held.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import psutil
from websockets.client import ClientProtocol
from websockets.frames import Frame, Opcode
from websockets.http11 import Response
from websockets.uri import parse_uri

from bench._live.clients import RawHttp
from bench._live.config import ADMIN, ROOT
from bench._live.server import ServerHandle
from bench._live.world import World
from bench._proc import free_port, rss_mb, stop
from bench._wsync import READ_BYTES, HandWs

#: The defaults the floods press on (docs/security.md, "Limits").
QUEUE_SIZE = 1000
QUEUE_BYTES = 8 * 2**20
OPS_PER_S = 500
MAX_TOPICS = 256
MAX_PENDING_REQUESTS = 50
MAX_COMMANDS_WAITING = 256
AGENT_MAX_SAMPLES = 200


class SlowWs(HandWs):
    """A :class:`HandWs` with a small receive buffer, for a reader that falls behind."""

    def __init__(self, url: str, token: str, rcvbuf: int = 4096) -> None:
        uri = parse_uri(url)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        self.sock.settimeout(30)
        self.sock.connect((uri.host, uri.port))
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.protocol = ClientProtocol(uri, max_size=4 * 1024 * 1024)
        self.frames = deque()
        request = self.protocol.connect()
        request.headers["Authorization"] = f"Bearer {token}"
        self.protocol.send_request(request)
        self._flush()
        events: list[Any] = []
        while not events:
            self._read()
            events = self.protocol.events_received()
        if not isinstance(events[0], Response) or events[0].status_code != 101:
            raise ConnectionError(f"handshake refused: {events[0]!r}")
        self.frames.extend(e for e in events[1:] if isinstance(e, Frame))

    def drain(self, quiet_s: float = 2.0) -> tuple[list[str], int | None]:
        """Read until ``quiet_s`` without data or the close: (text messages, close code)."""
        self.sock.settimeout(quiet_s)
        self.last_data = time.perf_counter()
        out: list[str] = []
        code = None
        while True:
            try:
                data = self.sock.recv(READ_BYTES)
            except TimeoutError:
                break
            except OSError:
                break
            if not data:
                self.protocol.receive_eof()
            else:
                self.last_data = time.perf_counter()
                self.protocol.receive_data(data)
            for e in self.protocol.events_received():
                if isinstance(e, Frame) and e.opcode is Opcode.TEXT:
                    out.append(e.data.decode())
                elif isinstance(e, Frame) and e.opcode is Opcode.CLOSE:
                    rcvd = self.protocol.close_rcvd
                    code = rcvd.code if rcvd is not None else None
            with contextlib.suppress(OSError):
                self._flush()
            if not data or code is not None:
                break
        return out, code


def _lagging(messages: Sequence[str]) -> tuple[int, int]:
    """(events, dropped as the ``lagging`` pushes count them)."""
    events = sum(1 for m in messages if m.startswith('{"op":"event"'))
    dropped = sum(
        int(json.loads(m).get("dropped", 0)) for m in messages if m.startswith('{"op":"lagging"')
    )
    return events, dropped


def _paced_publish(pubs: Sequence[HandWs], topic: str, data: str, count: int) -> None:
    """``count`` publishes, round robin over ``pubs``, each socket under its ops bound."""
    frame = json.dumps({"op": "publish", "topic": topic, "data": data})
    per_s = 0.9 * OPS_PER_S * len(pubs)
    start = time.perf_counter()
    for i in range(count):
        delay = start + i / per_s - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        pubs[i % len(pubs)].send(frame)


def _close(*sockets: HandWs) -> None:
    for ws in sockets:
        with contextlib.suppress(Exception):
            ws.close()


def flood_queue_frames(server: ServerHandle, world: World) -> dict[str, Any]:
    # 2 KiB messages: the queue's 1,000 hold 2 MiB (under the byte bound), and the
    # kernels' buffers (the server's send buffer grows to 4 MiB here) fewer than sent.
    topic, sent, size = "user/bench-pub/flood-frames", 6000, 2048
    sub = SlowWs(f"{server.ws}/ws/client", world.tokens["pub"])  # only bench-pub reads it
    assert sub.call("subscribe", "s", topics=[topic]).get("ok")
    pubs = [HandWs(f"{server.ws}/ws/client", world.tokens["pub"]) for _ in range(4)]
    _paced_publish(pubs, topic, "x" * size, sent)
    time.sleep(1)
    rss_flooded = rss_mb(server.pid)
    messages, code = sub.drain()
    events, dropped = _lagging(messages)
    _close(sub, *pubs)
    return {
        "flood": "send queue, frames",
        "bound": f"{QUEUE_SIZE:,} frames (FLEET_WS_QUEUE_SIZE): oldest dropped, lagging",
        "sent": f"{sent:,} x {size // 1024} KiB to a reader that never reads",
        "result": f"{events:,} delivered, {dropped:,} dropped (lagging), close {code}",
        # Delivered: the queue's 1,000 and what the two kernels' buffers held (a 4 KiB
        # receive buffer here; the server's send buffer); nothing unaccounted for.
        "held": dropped > 0 and events + dropped == sent and code is None,
        "rss_flooded_mb": rss_flooded,
    }


def flood_queue_bytes(server: ServerHandle, world: World) -> dict[str, Any]:
    topic, sent = "user/bench-pub/flood-bytes", 400
    sub = SlowWs(f"{server.ws}/ws/client", world.tokens["pub"])  # only bench-pub reads it
    assert sub.call("subscribe", "s", topics=[topic]).get("ok")
    pub = HandWs(f"{server.ws}/ws/client", world.tokens["pub"])
    rss_peak = 0.0
    frame = json.dumps({"op": "publish", "topic": topic, "data": "x" * 65536})
    for i in range(sent):
        pub.send(frame)
        if i % 20 == 0:
            rss_peak = max(rss_peak, rss_mb(server.pid))
            time.sleep(0.05)
    rss_peak = max(rss_peak, rss_mb(server.pid))
    messages, code = sub.drain()
    events, _ = _lagging(messages)
    _close(pub, sub)
    return {
        "flood": "send queue, bytes",
        "bound": "8 MiB (FLEET_WS_QUEUE_BYTES): closed 4429",
        "sent": f"{sent} x 64 KiB ({sent * 65536 / 2**20:.0f} MiB)",
        "result": f"{events} delivered, then close {code}",
        "held": code == 4429,
        "rss_flooded_mb": rss_peak,
    }


def flood_ops(server: ServerHandle, world: World) -> dict[str, Any]:
    sent = 2000
    pub = SlowWs(f"{server.ws}/ws/client", world.tokens["pub"], rcvbuf=1 << 20)
    frames = [
        json.dumps({"op": "publish", "id": str(i), "topic": "user/bench-pub/ops", "data": i})
        for i in range(sent)
    ]
    started = time.perf_counter()
    for frame in frames:
        pub.send(frame)
    took = time.perf_counter() - started
    messages, _ = pub.drain()
    # The last answer's arrival bounds the time the server spent on them: the bucket
    # (500, refilled at 500/s) lets through at most 500 + 500/s of that time.
    spent = pub.last_data - started
    acks = [json.loads(m) for m in messages if m.startswith('{"op":"ack"')]
    ok = sum(1 for a in acks if a.get("ok"))
    limited = sum(1 for a in acks if (a.get("error") or {}).get("code") == "rate_limited")
    _close(pub)
    return {
        "flood": "frames per second",
        "bound": f"{OPS_PER_S}/s a socket (FLEET_WS_OPS_PER_S): rate_limited",
        "sent": f"{sent:,} ops in {took:.2f} s",
        "result": f"{ok:,} ok, {limited:,} rate_limited, in {spent:.2f} s"
        f" (at most {OPS_PER_S * (1 + spent):,.0f} allowed)",
        "held": limited > 0 and ok + limited == sent and ok <= OPS_PER_S * (1 + spent),
    }


def flood_topics(server: ServerHandle, world: World) -> dict[str, Any]:
    ws = HandWs(f"{server.ws}/ws/client", world.tokens["pub"])
    topics = [f"user/bench-pub/t{i:03d}" for i in range(300)]
    taken = 0
    refusals: list[str] = []
    chunks = [topics[i : i + 64] for i in range(0, 256, 64)] + [topics[256:], topics[299:]]
    for n, chunk in enumerate(chunks):  # 64 (the most an op takes) x 4, then 44, then 1
        ack = ws.call("subscribe", f"t{n}", topics=chunk)
        if ack.get("ok"):
            taken += len(chunk)
        else:
            refusals.append((ack.get("error") or {}).get("code", "?"))
    _close(ws)
    return {
        "flood": "topics per socket",
        "bound": f"{MAX_TOPICS} (FLEET_WS_MAX_TOPICS): refused naming the bound",
        "sent": "300 topics: 64 an op x 4, then 44, then 1",
        "result": f"{taken} taken, {len(refusals)} ops refused"
        f" ({', '.join(sorted(set(refusals)))})",
        "held": taken == MAX_TOPICS and len(refusals) == 2,
    }


async def _instance(admin: RawHttp, vehicle_id: str) -> str:
    status, body = await admin.request(
        "POST", "/client/connect_instance", {"vehicle_id": vehicle_id}
    )
    assert status == 200, (status, body)
    return str(body["instance"]["instance_id"])


async def flood_requests(server: ServerHandle, world: World) -> dict[str, Any]:
    vid = world.vehicles[1][0]
    admin = await RawHttp(server.port, ADMIN).open()
    try:
        instance_id = await _instance(admin, vid)
        statuses: list[int] = []
        for i in range(60):
            name = f"soak-req-{i:02d}"
            status, body = await admin.request(
                "POST", "/api/users", {"username": name, "role": "operator", "vehicles": [vid]}
            )
            if status != 201:  # made by an earlier run on this server: not here
                raise RuntimeError(f"creating {name}: {status} {body}")
            user = await RawHttp(server.port, body["token"]).open()
            try:
                status, _ = await user.request(
                    "POST", "/client/request_control", {"instance_id": instance_id}
                )
            finally:
                await user.close()
            statuses.append(status)
        status, body = await admin.request(
            "GET", f"/client/control_requests?instance_id={instance_id}"
        )
        pending = len(body["requests"]) if status == 200 else -1
    finally:
        await admin.close()
    ok, refused = statuses.count(200), statuses.count(429)
    return {
        "flood": "pending control requests",
        "bound": f"{MAX_PENDING_REQUESTS} an instance (FLEET_MAX_PENDING_REQUESTS): 429",
        "sent": "60 operators ask for one instance",
        "result": f"{ok} stand, {refused} refused 429; {pending} pending listed",
        "held": ok == MAX_PENDING_REQUESTS and refused == 10 and pending == MAX_PENDING_REQUESTS,
    }


async def flood_commands(server: ServerHandle, world: World) -> dict[str, Any]:
    vid = world.vehicles[0][0]  # bench-op may see it
    admin = await RawHttp(server.port, ADMIN).open()
    op = await RawHttp(server.port, world.tokens["op"]).open()
    try:
        instance_id = await _instance(admin, vid)
        status, body = await admin.request(
            "POST",
            "/client/grant_control",
            {"instance_id": instance_id, "user": "bench-op", "duration_s": 3600},
        )
        assert status == 200, (status, body)
        statuses: list[int] = []
        codes: set[str] = set()
        for _ in range(300):
            status, body = await op.request(
                "POST",
                "/client/submit_control",
                {"instance_ids": [instance_id], "command": {"type": "keep_station"},
                 "ttl_s": 600},
            )  # fmt: skip
            statuses.append(status)
            if status != 202:
                error = (body or {}).get("error", {})
                codes.add(f"{error.get('code')}: {error.get('message')}")
        stop_status, _ = await op.request(
            "POST",
            "/client/submit_control",
            {"instance_ids": [instance_id], "command": {"type": "stop"}},
        )
    finally:
        await op.close()
        await admin.close()
    queued, refused = statuses.count(202), statuses.count(429)
    return {
        "flood": "commands waiting on one instance",
        "bound": f"{MAX_COMMANDS_WAITING} (server): 429, a stop always passes",
        "sent": "300 keep_station to a vehicle that never acks",
        "result": f"{queued} queued, {refused} refused ({', '.join(sorted(codes))});"
        f" stop: {stop_status}",
        "held": queued == MAX_COMMANDS_WAITING and refused == 300 - queued and stop_status == 202,
    }


def flood_outbox(workdir: Path) -> dict[str, Any]:
    db = workdir / "soak-agent.db"
    dead = free_port()  # nothing listens there
    env = {**os.environ, "FLEET_AGENT_TOKEN": "fct_soak-agent-never-used-0123456789"}
    cmd = [sys.executable, "-m", "vehicle_client.cli", "run", "--server",
           f"http://127.0.0.1:{dead}", "--vehicle-id", "soak-agent", "--outbox", str(db),
           "--rate-hz", "50", "--max-samples", str(AGENT_MAX_SAMPLES),
           "--log-level", "WARNING"]  # fmt: skip
    log = (workdir / "soak-agent.log").open("wb")
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
    rows_max, rss_max = 0, 0.0
    try:
        end = time.monotonic() + 15
        while time.monotonic() < end and proc.poll() is None:
            time.sleep(1)
            with contextlib.suppress(psutil.Error):
                rss_max = max(rss_max, psutil.Process(proc.pid).memory_info().rss / 2**20)
            with contextlib.suppress(sqlite3.Error):
                con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1)
                try:
                    rows_max = max(
                        rows_max, con.execute("SELECT count(*) FROM samples").fetchone()[0]
                    )
                finally:
                    con.close()
        alive = proc.poll() is None
    finally:
        stop(proc, signal.SIGINT)
        log.close()
    con = sqlite3.connect(db)
    try:
        rows = con.execute("SELECT count(*) FROM samples").fetchone()[0]
        meta = dict(con.execute("SELECT * FROM meta").fetchall())
    finally:
        con.close()
    dropped = int(meta.get("dropped", 0) or 0)
    return {
        "flood": "an agent's outbox",
        "bound": f"--max-samples {AGENT_MAX_SAMPLES}: the oldest dropped, counted",
        "sent": "50 Hz for 15 s, no server to reach",
        "result": f"{rows} rows at the end ({rows_max} at most seen), {dropped} dropped;"
        f" agent RSS {rss_max:.0f} MB",
        "held": alive
        and rows_max <= AGENT_MAX_SAMPLES
        and rows <= AGENT_MAX_SAMPLES
        and dropped > 0,
    }
