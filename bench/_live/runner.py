"""One live bench run: the server and brokers started, the sections chosen run, figures out."""

from __future__ import annotations

import contextlib
import os
import platform
import tempfile
from collections.abc import Callable
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import psutil
import websockets

from bench._live.capacity import capacity
from bench._live.clients import run_async
from bench._live.command import command_latency
from bench._live.config import BENCH_CORE, GOALS, SERVER_CORE, Config
from bench._live.layers import section_layers
from bench._live.pubsub import section_pubsub
from bench._live.server import fleet_server
from bench._live.world import build_world
from bench._mosquitto import mosquitto_version
from bench._proc import pinning, raise_nofile


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


def run_bench(cfg: Config, report: Callable[[str], None]) -> dict[str, Any]:
    out: dict[str, Any] = {"machine": machine(), "config": asdict(cfg), "goals": GOALS}
    nofile = raise_nofile()
    pinned = pinning()
    server_core = SERVER_CORE if pinned else None
    # The load generator's workers take every core but the server's; this process, one.
    bench_cores = sorted(os.sched_getaffinity(0) - {SERVER_CORE}) or [BENCH_CORE]
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
                        world,
                        cfg.cap_levels,
                        cfg.runs,
                        cfg.cap_window_s,
                        cfg.cap_warmup_s,
                        report,
                        cfg.gen_procs,
                        bench_cores if pinned else None,
                    )
                )
            with contextlib.suppress(OSError):
                tail = (workdir / "server.log").read_text(errors="replace").splitlines()[-5:]
                out["server_log_tail"] = tail
    return out
