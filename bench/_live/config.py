"""The live bench's constants (goals, the server's settings) and its command line."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ADMIN = "fct_bench-live-admin-0123456789abcdef"
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
    "capacity_vehicles": 10000,
    "capacity_cpu_pct": 100.0,
    "capacity_rss_mb": 600.0,
    "capacity_ack_median_ms": 20.0,
    "capacity_ack_p99_ms": 100.0,
}
#: Worker processes of the capacity load generator (``bench._live.loadgen``).
GEN_PROCS = 2
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
    gen_procs: int = GEN_PROCS


def parse_args(argv: Sequence[str] | None, description: str) -> tuple[Config, argparse.Namespace]:
    """The run's :class:`Config` and the parsed arguments of ``python -m bench.live_ws``."""
    parser = argparse.ArgumentParser(prog="python -m bench.live_ws", description=description)
    parser.add_argument("--quick", action="store_true", help="a short run: small capacity ramp")
    parser.add_argument("--runs", type=int, default=3, help="runs per figure (at least 3)")
    parser.add_argument(
        "--sections",
        default="pubsub,command,capacity,layers",
        help="comma list of pubsub, command, capacity, layers",
    )
    parser.add_argument("--count", type=int, default=None, help="latency messages per run")
    parser.add_argument("--levels", default=None, help="capacity ramp, e.g. 1000,5000,10000")
    parser.add_argument(
        "--gen-procs",
        type=int,
        default=GEN_PROCS,
        help="capacity: load generator worker processes (on the bench's cores)",
    )
    parser.add_argument("--window-s", type=float, default=None, help="capacity window per run")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args(argv)
    quick = args.quick
    levels = args.levels or ("100,250,1000" if quick else "1000,5000,10000")
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
        gen_procs=max(1, args.gen_procs),
    )
    return cfg, args
