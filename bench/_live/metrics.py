"""The live bench's figures as rows of ``python -m bench``'s common table."""

from __future__ import annotations

from typing import Any

from bench import Metric
from bench._live.config import GOALS


def metrics(out: dict[str, Any]) -> list[Metric]:
    """The figures as rows of ``python -m bench``'s table (values: one per run)."""
    rows: list[Metric] = []

    def add(name: str, unit: str, values: list[float], goal: tuple[str, float] | None = None):
        rows.append(Metric(name, unit, values, goal))

    if "pubsub" in out:
        for size, d in out["pubsub"]["latency"].items():
            f, m = d["fleet"], d["mosquitto"]
            for key, label in (("median_ms", "median"), ("p99_ms", "p99")):
                add(f"pub-sub {size} B {label}, fleet", "ms", [r[key] for r in f])
                add(f"pub-sub {size} B {label}, mosquitto", "ms", [r[key] for r in m])
                if "relay" in d:
                    add(f"pub-sub {size} B {label}, bare relay", "ms", [r[key] for r in d["relay"]])
            if "relay" in d:
                add(
                    f"pub-sub {size} B median fleet / bare relay",
                    "ratio",
                    [a["median_ms"] / b["median_ms"] for a, b in zip(f, d["relay"], strict=True)],
                )
            add(
                f"pub-sub {size} B median / mosquitto",
                "ratio",
                [a["median_ms"] / b["median_ms"] for a, b in zip(f, m, strict=True)],
                ("max", GOALS["pubsub_median_ratio"]),
            )
            add(
                f"pub-sub {size} B p99 / mosquitto",
                "ratio",
                [a["p99_ms"] / b["p99_ms"] for a, b in zip(f, m, strict=True)],
                ("max", GOALS["pubsub_p99_ratio"]),
            )
        t = out["pubsub"]["throughput"]
        add(f"throughput 1->1 {t['size']} B, fleet", "msg/s", [r["msgs_per_s"] for r in t["fleet"]])
        add(
            f"throughput 1->1 {t['size']} B, mosquitto",
            "msg/s",
            [r["msgs_per_s"] for r in t["mosquitto"]],
        )
    for r in out.get("command", []):
        at_goal = r["vehicles"] >= 1000
        add(
            f"command median @ {r['vehicles']} vehicles",
            "ms",
            [x["median_ms"] for x in r["runs"]],
            ("max", GOALS["command_median_ms"]) if at_goal else None,
        )
        add(
            f"command p99 @ {r['vehicles']} vehicles",
            "ms",
            [x["p99_ms"] for x in r["runs"]],
            ("max", GOALS["command_p99_ms"]) if at_goal else None,
        )
    if "capacity" in out:
        measured = [r for r in out["capacity"] if not r.get("skipped")]
        held = [r for r in measured if r["held"]]
        add(
            "capacity: vehicles held at 1 Hz",
            "vehicles",
            [float(held[-1]["vehicles"] if held else 0)],
            ("min", GOALS["capacity_vehicles"]),
        )
        for r in measured:
            n, runs = r["vehicles"], r["runs"]
            tag = "" if r["held"] else " (not held)"
            add(f"capacity @ {n}{tag}: server CPU", "% core", [x["server_cpu_pct"] for x in runs])
            add(f"capacity @ {n}{tag}: server RSS", "MB", [x["server_rss_mb"] for x in runs])
            at_goal = n >= GOALS["capacity_vehicles"]
            add(
                f"capacity @ {n}{tag}: ack median",
                "ms",
                [x["median_ms"] for x in runs],
                ("max", GOALS["capacity_ack_median_ms"]) if at_goal else None,
            )
            add(
                f"capacity @ {n}{tag}: ack p99",
                "ms",
                [x["p99_ms"] for x in runs],
                ("max", GOALS["capacity_ack_p99_ms"]) if at_goal else None,
            )
            add(
                f"capacity @ {n}{tag}: load gen CPU", "% core", [x["loadgen_cpu_pct"] for x in runs]
            )
    if "layers" in out:
        d = out["layers"]
        for key, label in (("median_ms", "median"), ("p99_ms", "p99")):
            add(f"three layers {d['size']} B {label}, fleet", "ms", [r[key] for r in d["fleet"]])
            add(
                f"three layers {d['size']} B {label}, mosquitto bridge",
                "ms",
                [r[key] for r in d["mosquitto_bridge"]],
            )
    return rows
