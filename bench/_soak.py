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
that a flood can press on is flooded, one after the other (``bench._floods``).
After each: the server still answers (``/readyz``, and a new socket's subscribe
acknowledged) and its RSS is read. A run prints its table; several runs
(``--runs``) are shown as min / median / max. This module is not picked up by
``python -m bench`` (its name starts with ``_``).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import httpx
import psutil

from bench._floods import (
    OPS_PER_S,
    flood_commands,
    flood_ops,
    flood_outbox,
    flood_queue_bytes,
    flood_queue_frames,
    flood_requests,
    flood_topics,
)
from bench._live.clients import run_async
from bench._live.config import BENCH_CORE, GEN_PROCS, SERVER_CORE
from bench._live.loadgen import ProcessLoadGenerator
from bench._live.server import ServerHandle, fleet_server
from bench._live.world import build_world
from bench._proc import pinning, raise_nofile, rss_mb
from bench._stats import lat_stats
from bench._wsync import HandWs

RETENTION_S = 60
SAMPLE_S = 5.0
GROWTH_GOAL = 0.10
SOAK_ENV = {"FLEET_RETENTION_S": str(RETENTION_S), "FLEET_WS_OPS_PER_S": str(OPS_PER_S)}


# ---- the server's state ------------------------------------------------------------------


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
