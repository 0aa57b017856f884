"""Print the figures ``make chaos`` collected (``FLEET_CHAOS_FIGURES``, JSON lines) as one
table: each test's measured values as min / median / max over its runs.

    python -m tests.chaos.table .cache/chaos/figures.jsonl
"""

from __future__ import annotations

import json
import platform
import statistics
import sys
from collections import defaultdict
from pathlib import Path


def main(path: str) -> None:
    runs: dict[str, list[dict]] = defaultdict(list)
    for line in Path(path).read_text().splitlines():
        if line.strip():
            row = json.loads(line)
            runs[row["test"]].append(row)
    print(f"machine: {platform.machine()}, {_cpu()}, Python {platform.python_version()}")
    print("| test | figure | runs | min | median | max |")
    print("|---|---|---|---|---|---|")
    for test, rows in sorted(runs.items()):
        names = [k for k in rows[0] if k not in ("test", "at", "full")]
        for name in names:
            values = [r[name] for r in rows if isinstance(r.get(name), int | float)]
            if not values:
                print(f"| {test} | {name} | {len(rows)} | {rows[0][name]} | | |")
                continue
            mid = statistics.median(values)
            print(
                f"| {test} | {name} | {len(values)} | {_fmt(min(values))} | {_fmt(mid)} "
                f"| {_fmt(max(values))} |"
            )


def _fmt(value: float) -> str:
    return f"{value:,.0f}" if value == int(value) else f"{value:.2f}"


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


if __name__ == "__main__":
    main(sys.argv[1])
