"""Section 3, capacity: vehicles at 1 Hz telemetry from several processes, ramping up; server
CPU and RSS."""

from __future__ import annotations

import asyncio
import gc
import statistics
import time
from collections.abc import Callable, Sequence
from typing import Any

import psutil

from bench._live.config import GOALS, HELD_FRACTION
from bench._live.loadgen import ProcessLoadGenerator
from bench._live.world import World, create_vehicles
from bench._stats import fmt3, lat_stats


async def capacity(
    world: World,
    levels: Sequence[int],
    runs: int,
    window_s: float,
    warmup_s: float,
    report: Callable[[str], None],
    procs: int = 2,
    cores: Sequence[int] | None = None,
) -> list[dict[str, Any]]:
    """Each level: vehicles added up to it, warm-up, ``runs`` windows measured. The load
    comes from ``procs`` worker processes pinned to ``cores`` (:mod:`bench._live.loadgen`)."""
    server_proc = psutil.Process(world.server.pid)
    gen = ProcessLoadGenerator(world.server.ws, procs, cores)
    results: list[dict[str, Any]] = []
    try:
        for level in levels:  # every level asked for, held or not (the table shows each)
            create_s = 0.0
            if level > len(world.vehicles):
                create_s = await create_vehicles(world, level)
            started = time.perf_counter()
            failures = await gen.add(world.vehicles[gen.count : level])
            connect_s = time.perf_counter() - started
            gc.collect()
            await asyncio.sleep(warmup_s)
            await gen.take_window()
            per_run: list[dict[str, Any]] = []
            closed = 0
            for _ in range(runs):
                s0, g0, w0 = server_proc.cpu_times(), gen.cpu_s(), time.perf_counter()
                rss_max = 0
                end = w0 + window_s
                while time.perf_counter() < end:
                    await asyncio.sleep(min(1.0, max(0.0, end - time.perf_counter())))
                    rss_max = max(rss_max, server_proc.memory_info().rss)
                s1, g1, w1 = server_proc.cpu_times(), gen.cpu_s(), time.perf_counter()
                window = await gen.take_window()
                wall = w1 - w0
                stats = lat_stats(window.pop("latencies"))
                closed = window["closed"]
                per_run.append(
                    {
                        **stats,
                        **window,
                        "server_cpu_pct": 100 * (s1.user + s1.system - s0.user - s0.system) / wall,
                        "loadgen_cpu_pct": 100 * (g1 - g0) / wall,
                        "server_rss_mb": rss_max / 2**20,
                        "acks_per_s": window["acked"] / wall,
                    }
                )
            errors = failures + sum(r["nacks"] for r in per_run) + closed
            result = {
                "vehicles": gen.count,
                "gen_procs": len(gen.procs),
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
                rate >= HELD_FRACTION * gen.count
                and statistics.median(r["median_ms"] for r in per_run)
                <= GOALS["capacity_ack_median_ms"]
                and errors == 0
            )
            result["bound"] = bound_by(result)
            results.append(result)
            report(
                f"  capacity @ {gen.count:>5}: server cpu"
                f" {fmt3([r['server_cpu_pct'] for r in per_run], 0)} %,"
                f" rss {fmt3([r['server_rss_mb'] for r in per_run], 0)} MB,"
                f" ack median {fmt3([r['median_ms'] for r in per_run], 1)} ms,"
                f" p99 {fmt3([r['p99_ms'] for r in per_run], 1)} ms,"
                f" loadgen cpu {fmt3([r['loadgen_cpu_pct'] for r in per_run], 0)} %,"
                f" acks/s {fmt3([r['acks_per_s'] for r in per_run], 0)}, errors {errors}"
            )
    finally:
        await gen.stop()
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
