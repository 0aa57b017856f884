"""Issue 3: the live path over WebSocket, side by side with Mosquitto, in one run.

One-hop pub-sub against Mosquitto, command latency at 1 / 100 / 1,000
vehicles, capacity at 1 Hz telemetry, and the three-layer route against
bridged Mosquitto; the bench itself is the package ``bench._live`` (its
docstring says how each figure is made).

    python -m bench.live_ws [--quick] [--runs 3] [--sections pubsub,command,capacity,layers]
                            [--levels 1000,2500,5000] [--json out.json]
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Sequence

from bench import Metric
from bench._live.config import parse_args
from bench._live.metrics import metrics
from bench._live.report import table
from bench._live.runner import run_bench

TITLE = "live path over WebSocket vs Mosquitto: pub-sub, commands, 1 Hz capacity, three layers"
DESCRIPTION = __doc__.splitlines()[0]


def run(runs: int) -> list[Metric]:
    """``python -m bench``: the full bench (no --quick); its own table goes to stderr."""
    cfg, _ = parse_args(["--runs", str(max(3, runs))], DESCRIPTION)

    def report(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    out = run_bench(cfg, report)
    print(table(out), file=sys.stderr, flush=True)
    return metrics(out)


def main(argv: Sequence[str] | None = None) -> int:
    cfg, args = parse_args(argv, DESCRIPTION)
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
