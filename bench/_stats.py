"""Latency statistics shared by the benches: percentiles, median / p99, spreads over runs."""

from __future__ import annotations

import statistics
from collections.abc import Sequence


def percentile(ordered: Sequence[float], q: float) -> float:
    """The nearest-rank ``q`` quantile of a sorted, non-empty sequence."""
    index = min(len(ordered) - 1, max(0, round(q * len(ordered)) - 1))
    return ordered[index]


def lat_stats(samples_ns: Sequence[int]) -> dict[str, float]:
    """Count, median, p99 and max in ms of latencies in ns (NaN figures if there are none)."""
    ordered = sorted(samples_ns)
    if not ordered:
        return {"count": 0, "median_ms": float("nan"), "p99_ms": float("nan")}
    return {
        "count": len(ordered),
        "median_ms": statistics.median(ordered) / 1e6,
        "p99_ms": percentile(ordered, 0.99) / 1e6,
        "max_ms": ordered[-1] / 1e6,
    }


def spread(values: Sequence[float]) -> tuple[float, float, float]:
    """(min, median, max) over runs."""
    return min(values), statistics.median(values), max(values)


def fmt3(values: Sequence[float], digits: int = 3) -> str:
    """``min / median / max`` over runs, ``digits`` after the point."""
    lo, mid, hi = spread(values)
    return f"{lo:.{digits}f} / {mid:.{digits}f} / {hi:.{digits}f}"
