"""Section (b) of ``bench/wan.py``: the multilayer paper's three routes, RTT by message
size, one message in flight (the module ``bench.wan`` describes each route)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import statistics
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import websockets

from bench._live.clients import ok, recv_json, ws_call, ws_connect
from bench._live.config import ADMIN, ROOT
from bench._proc import free_port, stop, wait_for_port

SIZES = (64, 1024, 8192, 65536)
ECHOES, ECHO_WARMUP = 30, 5
GATEWAY, LINK_GATEWAY, WORKER = "wan-gw", "wan-gw2", "wan-cloud"
UW, SURF, SIM, LINK = "wan-uw", "wan-surf", "wan-sim", "wan-link"


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


def world(base: str) -> dict[str, str]:
    """The vehicles, the two gateways and the cloud worker; their tokens."""
    with _admin(base) as admin:
        for vid in (UW, SURF, SIM, LINK):
            ok(
                admin.post(
                    "/api/vehicles", json={"vehicle_id": vid, "name": vid, "vehicle_type": "usv"}
                )
            )
        tokens = {
            "gateway": ok(
                admin.post(
                    "/api/gateways", json={"gateway_id": GATEWAY, "vehicles": [UW, SURF, SIM]}
                )
            ).json()["token"],
            "link": ok(
                admin.post("/api/gateways", json={"gateway_id": LINK_GATEWAY, "vehicles": [LINK]})
            ).json()["token"],
            "worker": ok(
                admin.post(
                    "/api/users",
                    json={"username": WORKER, "role": "viewer", "vehicles": [UW, SURF, LINK]},
                )
            ).json()["token"],
        }
    return tokens


@contextlib.contextmanager
def gateway_agent(
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


async def routes(
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


def size_name(size: int) -> str:
    return f"{size} B" if size < 1024 else f"{size // 1024} KiB"
