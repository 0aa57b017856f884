"""The seed papers' WAN figures, replayed through a 29 ms round trip (issue 15).

A real fleet-server (``python -m server.cli``, embedded store, rate limits out of
the way) and, in front of it, ``bench._faults.FaultProxy`` with a one-way delay
of 14.5 ms each way: the cloud-based paper's 29 ms round trip. The proxy runs in
its own process (``python -m bench.wan proxy UPSTREAM_PORT ONE_WAY_S``), so its timers and
the bench's clients do not share an interpreter lock.

(a) **Table 2.** Each seed method, one call at a time over keep-alive
    connections through the proxy with ``httpx`` (an operator's client and a
    vehicle's, as the paper's clients called its cloud server): ``connect_instance``
    (by vehicle id), ``get_param`` (every parameter and the position),
    ``submit_control`` (one ``go_to`` for an instance whose lease the operator
    holds; the vehicle acknowledges it ``done`` after each call, untimed, as a
    vehicle carrying it out would), ``update_param`` (one sample and two
    parameters), ``get_control`` (``wait_s=0``, nothing queued). Each call is
    paired with a ``GET /healthz`` on the same connection just before it, the
    baseline: the bare round trip through the proxy plus what a trivial route
    costs. The median of ``CALLS`` pairs after ``WARMUP``; a fresh vehicle,
    instance and lease each run. Goal: each method's median within the paired
    baseline's + 3 ms ("over RTT" rows); the absolute median sits beside the
    paper's average (in the row's name).

(b) **The multilayer paper's three routes**, RTT of an echoed JSON message by
    size (64 B, 1 KiB, 8 KiB, 64 KiB of payload, a JSON string), one message in
    flight, ``ECHOES`` after ``ECHO_WARMUP``. The proxy is on the surface → cloud
    hop (the WAN); the other links are loopback.

    1. unit → surface: the underwater unit (a local unit of a real gateway agent,
       ``fleet-agent gateway`` with ``listen``, connected to its unit WebSocket as
       ``wan-uw``) publishes on ``vehicle/wan-uw/ping``; the surface unit (another
       local unit of the same gateway, ``wan-surf``, standing for a program on the
       surface computer) has subscribed and publishes the same data back on
       ``vehicle/wan-surf/pong``. The gateway delivers both ways itself: nobody
       above asked for either topic, so nothing crosses the WAN.
    2. surface → cloud: the surface's own link, without the gateway agent: the
       bench holds a socket on ``/ws/vehicle`` with a second gateway's token (the
       socket the gateway agent keeps, driven by the bench) through the proxy and
       publishes for its vehicle ``wan-link``; the cloud unit, a user's worker on
       ``/ws/client`` connected to the server directly (it runs in the cloud),
       publishes the data back on ``user/wan-cloud/pong/wan-link``.
    3. unit → cloud through the gateway: ``wan-uw`` publishes on
       ``vehicle/wan-uw/up``; the real gateway agent sends it up (its
       ``forward_up`` holds it once the worker subscribed) over its link through
       the proxy; the worker answers on ``user/wan-cloud/pong/wan-uw``, which the
       gateway brings down to the unit. A surface unit attached to the gateway
       would take this same path to the cloud.

    The gateway runs with its defaults (``batch_tick_s`` 0.1: the ops it sends up
    during a tick leave as one ``batch`` frame) and simulates one vehicle of its
    own (``wan-sim``, 1 Hz telemetry over the same link), which it must have.

Not measured: TLS (the paper's server spoke HTTP), loss or jitter on the link, a
bandwidth limit (the proxy delays every byte by the same amount whatever the
rate), several calls in flight, and the paper's media path (RTSP).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import httpx
import websockets

from bench import Metric
from bench._faults import FaultProxy
from bench._live.clients import recv_json, ws_call, ws_connect
from bench._live.config import ADMIN, ROOT
from bench._live.server import fleet_server
from bench._proc import free_port, stop, wait_for_port

TITLE = "the paper's Table 2 and the multilayer routes through a 29 ms round trip"
ONE_WAY_S = 0.0145
#: The cloud-based paper's Table 2, average delay in ms.
PAPER_MS = {
    "connect_instance": 37,
    "get_param": 104,
    "submit_control": 31,
    "update_param": 127,
    "get_control": 29,
}
OVER_RTT_MS = 3.0
CALLS, WARMUP = 50, 10
SIZES = (64, 1024, 8192, 65536)
ECHOES, ECHO_WARMUP = 30, 5
GATEWAY, LINK_GATEWAY, WORKER = "wan-gw", "wan-gw2", "wan-cloud"
UW, SURF, SIM, LINK = "wan-uw", "wan-surf", "wan-sim", "wan-link"


# ---- the proxy, in its own process -------------------------------------------------
@contextlib.contextmanager
def wan_proxy(upstream_port: int, one_way_s: float = ONE_WAY_S) -> Iterator[int]:
    """A FaultProxy in front of ``upstream_port`` in a child process; yields its port."""
    process = subprocess.Popen(
        [sys.executable, "-m", "bench.wan", "proxy", str(upstream_port), str(one_way_s)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
    )
    try:
        assert process.stdout is not None
        line = process.stdout.readline().decode()
        if not line.strip().isdigit():
            raise RuntimeError(f"the WAN proxy did not start: {line!r}")
        yield int(line)
    finally:
        stop(process, signal.SIGTERM, 5)


def _serve_proxy(upstream_port: int, one_way_s: float) -> None:
    """The child: the proxy's port on stdout, then until SIGTERM."""
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM, signal.SIGINT})
    with FaultProxy(upstream_port, delay_s=one_way_s) as proxy:
        print(proxy.port, flush=True)
        signal.sigwait({signal.SIGTERM, signal.SIGINT})


# ---- (a) Table 2 ---------------------------------------------------------------------
def _paired_ms(client: httpx.Client, call: Any, after: Any = None) -> tuple[float, float]:
    """Medians of ``CALLS`` timed ``call()`` and as many ``GET /healthz`` on the same
    connection, alternated so that both see the same moments of a noisy machine
    (``WARMUP`` pairs first, not counted); ``after(answer)`` runs untimed."""
    calls, bare = [], []
    for i in range(WARMUP + CALLS):
        t = time.perf_counter()
        _ok(client.get("/healthz"))
        t1 = time.perf_counter()
        answer = call()
        t2 = time.perf_counter()
        if i >= WARMUP:
            bare.append((t1 - t) * 1000)
            calls.append((t2 - t1) * 1000)
        if after is not None:
            after(answer)
    return statistics.median(calls), statistics.median(bare)


def _ok(r: httpx.Response) -> httpx.Response:
    if r.status_code >= 400:
        raise RuntimeError(f"{r.request.method} {r.request.url.path}: {r.status_code} {r.text}")
    return r


def _table2_run(base: str, wan: str, run: int) -> dict[str, tuple[float, float]]:
    """One run: for each seed method, (its median, the paired baseline's), ms."""
    vid, user = f"wan-t2-{run}", f"wan-op-{run}"
    with httpx.Client(base_url=base, headers={"Authorization": f"Bearer {ADMIN}"}) as admin:
        vtoken = _ok(
            admin.post(
                "/api/vehicles", json={"vehicle_id": vid, "name": vid, "vehicle_type": "usv"}
            )
        ).json()["token"]
        otoken = _ok(
            admin.post("/api/users", json={"username": user, "role": "operator", "vehicles": [vid]})
        ).json()["token"]
        with httpx.Client(base_url=base, headers={"Authorization": f"Bearer {vtoken}"}) as v:
            iid = _ok(
                v.post(
                    "/upper/start_instance",
                    json={"vehicle_id": vid, "capabilities": ["stop", "go_to"]},
                )
            ).json()["instance_id"]
        _ok(
            admin.post(
                "/client/grant_control",
                json={"instance_id": iid, "user": user, "duration_s": 3600},
            )
        )
    seq = 0

    def update() -> None:
        nonlocal seq
        seq += 1
        sample = {
            "seq": seq,
            "ts": datetime.now(UTC).isoformat(),
            "lat": 43.94 + 1e-6 * seq,
            "lon": 15.44,
            "speed_mps": 0.4,
            "heading_deg": 90.0,
            "battery_pct": 80.0,
        }
        body = {"instance_id": iid, "params": {"mode": "auto", "seq": seq}, "samples": [sample]}
        _ok(vehicle.post("/upper/update_param", json=body))

    submit = {
        "instance_ids": [iid],
        "command": {"type": "go_to", "args": {"lat": 43.95, "lon": 15.45}},
        "ttl_s": 600,
    }
    out: dict[str, tuple[float, float]] = {}
    with (
        httpx.Client(base_url=wan, headers={"Authorization": f"Bearer {otoken}"}) as op,
        httpx.Client(base_url=wan, headers={"Authorization": f"Bearer {vtoken}"}) as vehicle,
    ):
        out["connect_instance"] = _paired_ms(
            op, lambda: _ok(op.post("/client/connect_instance", json={"vehicle_id": vid}))
        )
        out["update_param"] = _paired_ms(vehicle, update)
        out["get_param"] = _paired_ms(
            op, lambda: _ok(op.get("/client/get_param", params={"instance_id": iid}))
        )
        out["get_control"] = _paired_ms(
            vehicle,
            lambda: _ok(
                vehicle.get("/upper/get_control", params={"instance_id": iid, "wait_s": 0})
            ),
        )

        def done(answer: httpx.Response) -> None:
            """The vehicle carries the command out, as the paper's did: without it every
            submit finds one more unacknowledged command on the instance to read back."""
            acks = [
                {"command_id": c["command_id"], "status": "done"} for c in answer.json()["commands"]
            ]
            body = {"instance_id": iid, "control_mode": "remote", "acks": acks}
            _ok(vehicle.post("/upper/update_fbmessage", json=body))

        out["submit_control"] = _paired_ms(
            op, lambda: _ok(op.post("/client/submit_control", json=submit)), done
        )
    return out


def _table2(base: str, wan: str, runs: int) -> list[Metric]:
    rtt = Metric("baseline: GET /healthz through the proxy", "ms")
    absolute = {m: Metric(f"{m} (paper {ms} ms)", "ms") for m, ms in PAPER_MS.items()}
    over = {m: Metric(f"{m} over RTT", "ms", goal=("max", OVER_RTT_MS)) for m in PAPER_MS}
    for run in range(runs):
        got = _table2_run(base, wan, run)
        rtt.values.append(statistics.median(bare for _, bare in got.values()))
        for method in PAPER_MS:
            median, bare = got[method]
            absolute[method].values.append(median)
            over[method].values.append(median - bare)
    return [rtt, *absolute.values(), *over.values()]


# ---- (b) the routes ------------------------------------------------------------------
def _payload(size: int) -> str:
    return "x" * size


class _Echo:
    """Reads ``ws``; each event on a ``pings`` topic is published back on ``pongs[topic]``."""

    def __init__(self, ws: Any, pongs: dict[str, str]) -> None:
        self.ws, self.pongs = ws, pongs
        self.task = asyncio.create_task(self._run())

    async def _run(self) -> None:
        with contextlib.suppress(websockets.ConnectionClosed):
            async for frame in self.ws:
                if not isinstance(frame, str) or not frame.startswith('{"op":"event"'):
                    continue
                event = json.loads(frame)
                pong = self.pongs.get(event["topic"])
                if pong is not None:
                    await self.ws.send(
                        json.dumps({"op": "publish", "topic": pong, "data": event["data"]})
                    )


async def _rtt_ms(ws: Any, ping: dict[str, Any], pong_topic: str, size: int) -> float:
    """The median RTT of ``ECHOES`` pings of ``size`` bytes, one in flight."""
    payload = _payload(size)
    times = []
    for i in range(ECHO_WARMUP + ECHOES):
        data = f"{i:08d}" + payload[8:]
        frame = json.dumps({**ping, "data": data})
        t = time.perf_counter()
        await ws.send(frame)
        async with asyncio.timeout(30):
            while True:
                got = await ws.recv()
                if isinstance(got, str) and got.startswith('{"op":"event"'):
                    event = json.loads(got)
                    if event["topic"] == pong_topic and event["data"][:8] == f"{i:08d}":
                        break
        if i >= ECHO_WARMUP:
            times.append((time.perf_counter() - t) * 1000)
    return statistics.median(times)


async def _wait_routes(ws: Any, topic: str, consumer: str) -> None:
    """Until a ``routes`` push says ``consumer`` takes ``topic`` from this unit."""
    async with asyncio.timeout(30):
        while True:
            frame = await recv_json(ws)
            if frame.get("op") == "routes" and consumer in frame.get("produces", {}).get(topic, []):
                return


def _admin(base: str) -> httpx.Client:
    return httpx.Client(base_url=base, headers={"Authorization": f"Bearer {ADMIN}"}, timeout=30)


def _world(base: str) -> dict[str, str]:
    """The vehicles, the two gateways and the cloud worker; their tokens."""
    with _admin(base) as admin:
        for vid in (UW, SURF, SIM, LINK):
            _ok(
                admin.post(
                    "/api/vehicles", json={"vehicle_id": vid, "name": vid, "vehicle_type": "usv"}
                )
            )
        tokens = {
            "gateway": _ok(
                admin.post(
                    "/api/gateways", json={"gateway_id": GATEWAY, "vehicles": [UW, SURF, SIM]}
                )
            ).json()["token"],
            "link": _ok(
                admin.post("/api/gateways", json={"gateway_id": LINK_GATEWAY, "vehicles": [LINK]})
            ).json()["token"],
            "worker": _ok(
                admin.post(
                    "/api/users",
                    json={"username": WORKER, "role": "viewer", "vehicles": [UW, SURF, LINK]},
                )
            ).json()["token"],
        }
    return tokens


@contextlib.contextmanager
def _gateway_agent(
    workdir: Path, wan_port: int, token: str, batch_tick_s: float | None
) -> Iterator[int]:
    """``fleet-agent gateway`` with its link through the proxy; yields its units' port."""
    port = free_port()
    config = workdir / "gateway.toml"
    tick = "" if batch_tick_s is None else f"batch_tick_s = {batch_tick_s}\n"
    config.write_text(
        f'server = "http://127.0.0.1:{wan_port}"\nlisten = "127.0.0.1:{port}"\n'
        f'outbox_dir = "{workdir / "gw-outbox"}"\nlog_level = "WARNING"\n{tick}'
        f'[[vehicles]]\nvehicle_id = "{SIM}"\n'
    )
    log = (workdir / "gateway.log").open("wb")
    process = subprocess.Popen(
        [sys.executable, "-m", "vehicle_client.cli", "gateway", "--config", str(config)],
        cwd=ROOT,
        env={**os.environ, "FLEET_AGENT_TOKEN": token},
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    try:
        wait_for_port(port, process, "fleet-agent gateway", 60)
        yield port
    finally:
        stop(process, signal.SIGTERM, 10)
        log.close()


async def _routes(
    base: str, wan_port: int, unit_port: int, tokens: dict[str, str], runs: int, routes: set[int]
) -> dict[tuple[int, int], list[float]]:
    ws_base, wan_ws = base.replace("http", "ws", 1), f"ws://127.0.0.1:{wan_port}"
    ping_uw, pong_surf = f"vehicle/{UW}/ping", f"vehicle/{SURF}/pong"
    up_uw, pong_uw = f"vehicle/{UW}/up", f"user/{WORKER}/pong/{UW}"
    up_link, pong_link = f"vehicle/{LINK}/up", f"user/{WORKER}/pong/{LINK}"
    results: dict[tuple[int, int], list[float]] = {}
    worker = await ws_connect(f"{ws_base}/ws/client", tokens["worker"])
    link = await ws_connect(f"{wan_ws}/ws/vehicle", tokens["link"])
    uw = await websockets.connect(
        f"ws://127.0.0.1:{unit_port}/?vehicle_id={UW}", compression=None, max_size=2**22
    )
    surf = await websockets.connect(
        f"ws://127.0.0.1:{unit_port}/?vehicle_id={SURF}", compression=None, max_size=2**22
    )
    try:
        # Route 1: both units on the gateway; route 3: the unit's topic wanted above.
        for op, topics in (("register", [ping_uw, up_uw]), ("subscribe", [pong_surf, pong_uw])):
            ack = await ws_call(uw, op, "u-" + op, topics=topics)
            assert ack["ok"], ack
        for op, topics in (("register", [pong_surf]), ("subscribe", [ping_uw])):
            ack = await ws_call(surf, op, "s-" + op, topics=topics)
            assert ack["ok"], ack
        for op, topics in (("register", [up_link]), ("subscribe", [pong_link])):
            ack = await ws_call(link, op, "l-" + op, vehicle_id=LINK, topics=topics)
            assert ack["ok"], ack
        ack = await ws_call(worker, "subscribe", "w", topics=[up_uw, up_link])
        assert ack["ok"], ack
        await _wait_routes(uw, up_uw, f"user:{WORKER}")
        echoes = [
            _Echo(surf, {ping_uw: pong_surf}),
            _Echo(worker, {up_uw: pong_uw, up_link: pong_link}),
        ]
        for _ in range(runs):
            for size in SIZES:
                if 1 in routes:
                    results.setdefault((1, size), []).append(
                        await _rtt_ms(uw, {"op": "publish", "topic": ping_uw}, pong_surf, size)
                    )
                if 2 in routes:
                    ping = {"op": "publish", "vehicle_id": LINK, "topic": up_link}
                    results.setdefault((2, size), []).append(
                        await _rtt_ms(link, ping, pong_link, size)
                    )
                if 3 in routes:
                    results.setdefault((3, size), []).append(
                        await _rtt_ms(uw, {"op": "publish", "topic": up_uw}, pong_uw, size)
                    )
        for echo in echoes:
            echo.task.cancel()
    finally:
        for ws in (uw, surf, link, worker):
            await ws.close()
    return results


ROUTE_NAMES = {
    1: "route 1 unit -> surface (loopback)",
    2: "route 2 surface -> cloud (WAN)",
    3: "route 3 unit -> gateway -> cloud",
}


def _size(size: int) -> str:
    return f"{size} B" if size < 1024 else f"{size // 1024} KiB"


def run(runs: int) -> list[Metric]:
    with tempfile.TemporaryDirectory(prefix="bench-wan-") as tmp:
        workdir = Path(tmp)
        with fleet_server(workdir, None) as server, wan_proxy(server.port) as wan_port:
            wan = f"http://127.0.0.1:{wan_port}"
            metrics = _table2(server.base, wan, runs)
            tokens = _world(server.base)
            with _gateway_agent(workdir, wan_port, tokens["gateway"], None) as unit_port:
                results = asyncio.run(
                    _routes(server.base, wan_port, unit_port, tokens, runs, {1, 2, 3})
                )
            # The same gateway sending each op up at once (no batch tick).
            with _gateway_agent(workdir, wan_port, tokens["gateway"], 0) as unit_port:
                untick = asyncio.run(_routes(server.base, wan_port, unit_port, tokens, runs, {3}))
    for (route, size), values in sorted(results.items()):
        metrics.append(Metric(f"{ROUTE_NAMES[route]}, {_size(size)} RTT", "ms", values))
    for (_, size), values in sorted(untick.items()):
        name = f"{ROUTE_NAMES[3]}, {_size(size)} RTT, batch_tick_s 0"
        metrics.append(Metric(name, "ms", values))
    return metrics


if __name__ == "__main__":
    if sys.argv[1:2] == ["proxy"]:
        _serve_proxy(int(sys.argv[2]), float(sys.argv[3]))
    else:
        for m in run(int(sys.argv[1]) if len(sys.argv) > 1 else 1):
            print(m.name, m.unit, [round(v, 2) for v in m.values], m.goal)
