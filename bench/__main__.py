"""Run every bench module present and print one table (min / median / max of ``--runs``).

Modules with ``run(runs)`` (see ``bench/__init__.py``) fill the table; a module
with only its own ``main()`` is run once as ``python -m bench.<name>`` and its
report printed after the table; helper modules (``_*``, or neither) are skipped.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

from bench import Metric


def modules(only: list[str] | None) -> list[str]:
    here = Path(__file__).parent
    names = sorted(m.name for m in pkgutil.iter_modules([str(here)]) if not m.name.startswith("_"))
    return [n for n in names if not only or n in only]


def fmt(value: float) -> str:
    if value >= 100:
        return f"{value:,.0f}"
    if value >= 1:
        return f"{value:.2f}"
    return f"{value:.3f}"


def table(rows: list[tuple[str, Metric]]) -> str:
    head = ("bench", "metric", "unit", "min", "median", "max", "goal", "met")
    lines = [head]
    for module, m in rows:
        med = statistics.median(m.values)
        goal = "" if m.goal is None else ("≥ " if m.goal[0] == "min" else "≤ ") + fmt(m.goal[1])
        met = m.met(med)
        lines.append(
            (
                module,
                m.name,
                m.unit,
                fmt(min(m.values)),
                fmt(med),
                fmt(max(m.values)),
                goal,
                "" if met is None else ("yes" if met else "NO"),
            )
        )
    widths = [max(len(str(r[i])) for r in lines) for i in range(len(head))]
    out = [
        "| " + " | ".join(str(c).ljust(w) for c, w in zip(r, widths, strict=True)) + " |"
        for r in lines
    ]
    out.insert(1, "|" + "|".join("-" * (w + 2) for w in widths) + "|")
    return "\n".join(out)


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__)
    parser.add_argument("--runs", type=int, default=3, help="repetitions of each measurement")
    parser.add_argument("--only", nargs="*", help="bench modules to run (default: all)")
    args = parser.parse_args()
    if args.runs < 1:
        parser.error("--runs must be at least 1")
    rows: list[tuple[str, Metric]] = []
    started = time.perf_counter()
    others: list[tuple[str, str]] = []
    for name in modules(args.only):
        module = importlib.import_module(f"bench.{name}")
        if hasattr(module, "run"):
            print(f"# {name}: {module.TITLE} ...", file=sys.stderr, flush=True)
            for metric in module.run(args.runs):
                rows.append((name, metric))
        elif hasattr(module, "main"):
            # A bench with its own command line: run once, its report shown as it prints it.
            print(f"# {name} (own report) ...", file=sys.stderr, flush=True)
            done = subprocess.run(
                [sys.executable, "-m", f"bench.{name}"], capture_output=True, text=True, check=False
            )
            others.append((name, (done.stdout + done.stderr[-2000:]).strip()))
    print(
        f"python {platform.python_version()}, {args.runs} runs, "
        f"{time.perf_counter() - started:.0f} s in all"
    )
    print(table(rows))
    for name, report in others:
        print(f"\n## {name}\n{report}")
    failed = [m for _, m in rows if m.met(statistics.median(m.values)) is False]
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
