"""Soak (issue 15, ``make soak``): 1,000 vehicles for 10 minutes, then the bounds flooded.

    python -m bench._soak [--minutes 10] [--vehicles 1000] [--runs 1] [--json out.json]

A real ``fleet-server`` (``python -m server.cli``, embedded store, pinned to core 0 as
in ``bench.live_ws``) with a short retention (``FLEET_RETENTION_S``, 60 s: the
retention loop, every 60 s, drops telemetry, events and finished commands older
than that, so what is stored stays bounded), the bench's raised HTTP rate limit
(setting up 1,000 vehicles from one admin token) and every other bound at its
default (``FLEET_WS_OPS_PER_S`` put back to 500). The vehicles stream at 1 Hz over
``/ws/vehicle`` from the capacity bench's multi-process load generator
(``bench._live.loadgen``) for ``--minutes``; the server's RSS is read every 5 s.
After the warm-up (2 minutes, a fifth of a shorter run) the RSS at the end (the
median of the last 30 s) must be within 10 % of the RSS just after the warm-up (the
median of the 30 s after it); the peak is shown too.

Then, the vehicles still streaming, each bound of ``docs/security.md`` ("Limits")
that a flood can press on, one after the other:

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

After each: the server still answers (``/readyz``, and a new socket's subscribe
acknowledged) and its RSS is read. A run prints its table; several runs
(``--runs``) are shown as min / median / max. This module is not picked up by
``python -m bench`` (its name starts with ``_``).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import platform
import signal
import socket
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import httpx
import psutil
from websockets.client import ClientProtocol
from websockets.frames import Frame, Opcode
from websockets.http11 import Response
from websockets.uri import parse_uri

from bench._live.clients import RawHttp, run_async
from bench._live.config import ADMIN, BENCH_CORE, GEN_PROCS, ROOT, SERVER_CORE
from bench._live.loadgen import ProcessLoadGenerator
from bench._live.server import ServerHandle, fleet_server
from bench._live.world import World, build_world
from bench._proc import free_port, pinning, raise_nofile, stop
from bench._stats import lat_stats
from bench._wsync import READ_BYTES, HandWs

RETENTION_S = 60
SAMPLE_S = 5.0
#: The defaults the floods press on (docs/security.md, "Limits").
QUEUE_SIZE = 1000
QUEUE_BYTES = 8 * 2**20
OPS_PER_S = 500
MAX_TOPICS = 256
MAX_PENDING_REQUESTS = 50
MAX_COMMANDS_WAITING = 256
AGENT_MAX_SAMPLES = 200
GROWTH_GOAL = 0.10
SOAK_ENV = {"FLEET_RETENTION_S": str(RETENTION_S), "FLEET_WS_OPS_PER_S": str(OPS_PER_S)}


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


# ---- the server's state ------------------------------------------------------------------


def rss_mb(pid: int) -> float:
    return float(psutil.Process(pid).memory_info().rss / 2**20)


def stored_mb(workdir: Path) -> float:
    """The embedded store's files (snapshot and journal) in MB."""
    return sum(p.stat().st_size for p in workdir.glob("fleet-store.snapshot*")) / 2**20


def answering(server: ServerHandle, token: str) -> bool:
    """``/readyz`` 200 and a new ``/ws/client`` socket's subscribe acknowledged."""
    try:
        if httpx.get(f"{server.base}/readyz", timeout=5).status_code != 200:
            return False
        ws = HandWs(f"{server.ws}/ws/client", token, timeout_s=10)
        try:
            return bool(ws.call("subscribe", "probe", topics=["user/bench-sub/probe"]).get("ok"))
        finally:
            ws.close()
    except (OSError, httpx.HTTPError, ConnectionError):
        return False


# ---- the floods --------------------------------------------------------------------------


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


# ---- one run -----------------------------------------------------------------------------


async def soak_run(
    server: ServerHandle,
    workdir: Path,
    vehicles: int,
    minutes: float,
    warmup_min: float,
    procs: int,
    cores: Sequence[int] | None,
    report: Callable[[str], None],
) -> dict[str, Any]:
    world = await build_world(server, vehicles)
    report(f"  setup: {vehicles} vehicles in {world.setup_s:.1f} s")
    gen = ProcessLoadGenerator(server.ws, procs, cores)
    server_proc = psutil.Process(server.pid)
    try:
        failures = await gen.add(world.vehicles)
        report(f"  connected {gen.count} ({failures} failures); soaking {minutes:g} min")
        await gen.take_window()
        samples: list[tuple[float, float]] = []  # (s since start, RSS MB)
        minutes_out: list[dict[str, Any]] = []
        latencies: list[int] = []
        counts = {"sent": 0, "acked": 0, "nacks": 0, "late": 0}
        closed = 0
        cpu0, t0 = server_proc.cpu_times(), time.perf_counter()
        stored_warm = 0.0
        next_window = 60.0
        while (now := time.perf_counter() - t0) < minutes * 60:
            samples.append((now, rss_mb(server.pid)))
            if stored_warm == 0.0 and now >= warmup_min * 60:
                stored_warm = stored_mb(workdir)
            if now >= next_window or now + SAMPLE_S >= minutes * 60:
                window = await gen.take_window()
                lat = window.pop("latencies")
                stats = lat_stats(lat)
                if now >= warmup_min * 60:
                    latencies.extend(lat)
                for key in counts:
                    counts[key] += window[key]
                closed = window["closed"]
                minutes_out.append({"t_s": now, "rss_mb": samples[-1][1], **stats, **window})
                report(
                    f"  {now / 60:5.1f} min: RSS {samples[-1][1]:.0f} MB, acks {window['acked']},"
                    f" median {stats['median_ms']:.1f} ms, p99 {stats['p99_ms']:.1f} ms,"
                    f" late {window['late']}, closed {closed}, stored {stored_mb(workdir):.1f} MB"
                )
                next_window += 60.0
            await asyncio.sleep(SAMPLE_S)
        cpu1, t1 = server_proc.cpu_times(), time.perf_counter()
        warm = warmup_min * 60
        base = [r for t, r in samples if warm <= t < warm + 30] or [samples[-1][1]]
        tail = [r for t, r in samples if t >= samples[-1][0] - 30]
        after = [r for t, r in samples if t >= warm]
        rss_base, rss_end = statistics.median(base), statistics.median(tail)
        lat = lat_stats(latencies)
        out: dict[str, Any] = {
            "vehicles": gen.count,
            "connect_failures": failures,
            "minutes": minutes,
            "warmup_min": warmup_min,
            "rss_start_mb": samples[0][1],
            "rss_warm_mb": rss_base,
            "rss_end_mb": rss_end,
            "rss_peak_mb": max(after),
            "growth_pct": 100 * (rss_end / rss_base - 1),
            "peak_growth_pct": 100 * (max(after) / rss_base - 1),
            "stored_warm_mb": stored_warm,
            "stored_end_mb": stored_mb(workdir),
            "server_cpu_pct": 100 * (cpu1.user + cpu1.system - cpu0.user - cpu0.system) / (t1 - t0),
            "ack_median_ms": lat["median_ms"],
            "ack_p99_ms": lat["p99_ms"],
            **counts,
            "errors": failures + counts["nacks"] + closed,
            "rss_samples": samples,
            "per_minute": minutes_out,
        }
        report(
            f"  soak: RSS {rss_base:.0f} -> {rss_end:.0f} MB ({out['growth_pct']:+.1f} %),"
            f" peak {out['rss_peak_mb']:.0f} MB; errors {out['errors']}"
        )
        floods: list[dict[str, Any]] = []
        steps: list[tuple[str, Callable[[], Any]]] = [
            ("queue frames", lambda: asyncio.to_thread(flood_queue_frames, server, world)),
            ("queue bytes", lambda: asyncio.to_thread(flood_queue_bytes, server, world)),
            ("ops", lambda: asyncio.to_thread(flood_ops, server, world)),
            ("topics", lambda: asyncio.to_thread(flood_topics, server, world)),
            ("requests", lambda: flood_requests(server, world)),
            ("commands", lambda: flood_commands(server, world)),
            ("outbox", lambda: asyncio.to_thread(flood_outbox, workdir)),
        ]
        for name, step in steps:
            before = rss_mb(server.pid)
            try:
                result = await step()
            except Exception as exc:  # a flood that broke is a figure, not the end of the run
                result = {"flood": name, "bound": "?", "sent": "?", "result": repr(exc)[:200],
                          "held": False}  # fmt: skip
            await asyncio.sleep(2)
            result["rss_before_mb"] = before
            result["rss_after_mb"] = rss_mb(server.pid)
            result["answering"] = await asyncio.to_thread(answering, server, world.tokens["sub"])
            floods.append(result)
            report(
                f"  flood {result['flood']}: {result['result']}; held {result['held']},"
                f" RSS {before:.0f} -> {result['rss_after_mb']:.0f} MB,"
                f" answering {result['answering']}"
            )
        window = await gen.take_window()
        lat = lat_stats(window.pop("latencies"))
        out["after_floods"] = {**lat, **window}
        out["floods"] = floods
        out["rss_final_mb"] = rss_mb(server.pid)
        return out
    finally:
        await gen.stop()


def one_run(args: argparse.Namespace, report: Callable[[str], None]) -> dict[str, Any]:
    pinned = pinning()
    cores = sorted(os.sched_getaffinity(0) - {SERVER_CORE}) if pinned else None
    with tempfile.TemporaryDirectory(prefix="bench-soak-") as tmp:
        workdir = Path(tmp)
        with fleet_server(workdir, SERVER_CORE if pinned else None, SOAK_ENV) as server:
            return dict(
                run_async(
                    soak_run(
                        server,
                        workdir,
                        args.vehicles,
                        args.minutes,
                        args.warmup_min,
                        args.gen_procs,
                        cores,
                        report,
                    )
                )
            )


# ---- the table ---------------------------------------------------------------------------


def _f3(values: Sequence[float], digits: int = 0) -> str:
    if len(values) == 1:
        return f"{values[0]:.{digits}f}"
    lo, mid, hi = min(values), statistics.median(values), max(values)
    return f"{lo:.{digits}f} / {mid:.{digits}f} / {hi:.{digits}f}"


def table(runs: Sequence[dict[str, Any]]) -> str:
    first = runs[0]
    lines = [
        f"Soak: {first['vehicles']} vehicles at 1 Hz over /ws/vehicle for {first['minutes']:g} min"
        f" (warm-up {first['warmup_min']:g} min), FLEET_RETENTION_S={RETENTION_S};"
        f" {len(runs)} run(s)" + (", figures min / median / max" if len(runs) > 1 else ""),
        "",
        "| figure | value | goal | met |",
        "|---|---|---|---|",
    ]

    def row(name: str, key: str, digits: int = 0, goal: str = "", met: bool | None = None):
        vals = [float(r[key]) for r in runs]
        flag = "" if met is None else ("yes" if met else "NO")
        lines.append(f"| {name} | {_f3(vals, digits)} | {goal} | {flag} |")

    growth_ok = all(r["growth_pct"] < 100 * GROWTH_GOAL for r in runs)
    row("server RSS at the start of the soak, MB", "rss_start_mb")
    row("server RSS after warm-up, MB", "rss_warm_mb")
    row("server RSS at the end, MB", "rss_end_mb")
    row("RSS growth after warm-up, %", "growth_pct", 1, "< 10 %", growth_ok)
    row("RSS peak after warm-up, % over warm-up", "peak_growth_pct", 1)
    row("stored (snapshot + journal) after warm-up, MB", "stored_warm_mb", 1)
    row("stored at the end, MB", "stored_end_mb", 1)
    row("server CPU, % of a core", "server_cpu_pct")
    row("acks over the soak", "acked")
    row("ack median after warm-up, ms", "ack_median_ms", 1)
    row("ack p99 after warm-up, ms", "ack_p99_ms", 1)
    row("errors (connect failures, nacks, closed)", "errors", 0, "0",
        all(r["errors"] == 0 for r in runs))  # fmt: skip
    row("server RSS after the floods, MB", "rss_final_mb")
    lines += [
        "",
        "| flood | bound | sent | result (last run) | held | RSS before -> after, MB | answering |",
        "|---|---|---|---|---|---|---|",
    ]
    for i, f in enumerate(first["floods"]):
        each = [r["floods"][i] for r in runs]
        held = all(x["held"] for x in each)
        answering = all(x["answering"] for x in each)
        before = _f3([x["rss_before_mb"] for x in each])
        after = _f3([x["rss_after_mb"] for x in each])
        last = each[-1]
        lines.append(
            f"| {f['flood']} | {f['bound']} | {last['sent']} | {last['result']} |"
            f" {'yes' if held else 'NO'} | {before} -> {after} | {'yes' if answering else 'NO'} |"
        )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench._soak", description=__doc__)
    parser.add_argument("--minutes", type=float, default=10.0, help="length of the soak")
    parser.add_argument("--warmup-min", type=float, default=None, help="default: 2, or a fifth")
    parser.add_argument("--vehicles", type=int, default=1000)
    parser.add_argument("--runs", type=int, default=1, help="whole soaks, one after the other")
    parser.add_argument("--gen-procs", type=int, default=GEN_PROCS)
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args(argv)
    if args.warmup_min is None:
        args.warmup_min = min(2.0, args.minutes / 5)
    nofile = raise_nofile()
    if args.vehicles + 200 > nofile:
        parser.error(f"ulimit -n is {nofile}: too low for {args.vehicles} sockets")
    if pinning():
        os.sched_setaffinity(0, {BENCH_CORE})
    started = time.perf_counter()

    def report(line: str) -> None:
        print(f"[{time.perf_counter() - started:7.1f}s]{line}", file=sys.stderr, flush=True)

    runs = []
    for n in range(max(1, args.runs)):
        report(f" run {n + 1} of {args.runs}")
        runs.append(one_run(args, report))
    print(f"python {platform.python_version()}, {time.perf_counter() - started:.0f} s in all")
    print(table(runs))
    if args.json:
        args.json.write_text(json.dumps(runs, indent=2, default=str))
    ok = all(
        r["growth_pct"] < 100 * GROWTH_GOAL
        and r["errors"] == 0
        and all(f["held"] and f["answering"] for f in r["floods"])
        for r in runs
    )
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
