"""Section 3, capacity: vehicles at 1 Hz telemetry, ramping up; server CPU and RSS."""

from __future__ import annotations

import asyncio
import contextlib
import gc
import json
import statistics
import time
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from typing import Any

import psutil
import websockets

from bench._live.clients import close_all
from bench._live.config import GOALS, HELD_FRACTION
from bench._live.world import VehicleSocket, World, connect_vehicles, create_vehicles
from bench._stats import fmt3, lat_stats


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
