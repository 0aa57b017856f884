"""The live bench's printed table (figures min / median / max over runs, goals met or not)."""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from typing import Any

from bench._live.config import GOALS, HELD_FRACTION, WINDOW
from bench._stats import fmt3


def verdict(ok: bool) -> str:
    return "MET" if ok else "MISSED"


def _col(runs: Sequence[dict[str, Any]], key: str, digits: int = 3) -> str:
    return fmt3([r[key] for r in runs], digits)


def _mid(runs: Sequence[dict[str, Any]], key: str) -> float:
    return statistics.median(r[key] for r in runs)


def table(out: dict[str, Any]) -> str:
    m = out["machine"]
    lines = [
        f"Issue 3 live path: fleet-server over WebSocket vs Mosquitto {m['mosquitto']}"
        f" (QoS 0), {out['config']['runs']} runs each, figures min / median / max over runs",
        f"machine: {m['nproc']} CPU ({m['cpu']}), {m['ram_gib']} GiB RAM, Python {m['python']},"
        f" websockets {m['websockets']}, {m['date']};"
        + (" server and brokers on core 0, bench on core 1" if m["pinned"] else " not pinned"),
        "",
    ]
    if "pubsub" in out:
        p = out["pubsub"]
        c = out["config"]
        lines += [
            f"1. one-hop pub-sub latency (one message in flight, {c['count']} messages"
            f" after {c['warmup']} warm-up, per run; clients driven by hand from one"
            " thread, as paho is for mosquitto; 'fleet, asyncio': asyncio websockets clients), ms",
            f"   {'size':>8}  {'path':<14} {'median':>26} {'p99':>26}",
        ]
        for size, d in p["latency"].items():
            named = [("fleet /ws", d["fleet"]), ("mosquitto", d["mosquitto"])]
            if "relay" in d:
                named.append(("bare relay", d["relay"]))
            if "fleet_asyncio" in d:
                named.append(("fleet, asyncio", d["fleet_asyncio"]))
            for name, runs in named:
                lines.append(
                    f"   {int(size):>8}  {name:<14} {_col(runs, 'median_ms'):>26}"
                    f" {_col(runs, 'p99_ms'):>26}"
                )
            rm = _mid(d["fleet"], "median_ms") / _mid(d["mosquitto"], "median_ms")
            rp = _mid(d["fleet"], "p99_ms") / _mid(d["mosquitto"], "p99_ms")
            lines.append(
                f"   {int(size):>8}  {'fleet/mosq.':<14} {rm:>20.2f}x {'':>4} {rp:>20.2f}x"
                f"   goal <= {GOALS['pubsub_median_ratio']}x median"
                f" {verdict(rm <= GOALS['pubsub_median_ratio'])},"
                f" <= {GOALS['pubsub_p99_ratio']}x p99 {verdict(rp <= GOALS['pubsub_p99_ratio'])}"
            )
            if "relay" in d:
                for label, base in (("relay/mosq.", d["mosquitto"]), ("fleet/relay", None)):
                    top = d["relay"] if base is not None else d["fleet"]
                    bottom = base if base is not None else d["relay"]
                    lines.append(
                        f"   {int(size):>8}  {label:<14}"
                        f" {_mid(top, 'median_ms') / _mid(bottom, 'median_ms'):>20.2f}x {'':>4}"
                        f" {_mid(top, 'p99_ms') / _mid(bottom, 'p99_ms'):>20.2f}x"
                    )
        t = p["throughput"]
        lines += [
            f"   throughput one publisher -> one subscriber, {t['size']} B,"
            f" <= {WINDOW} in flight, {c['tp_count']} messages: msgs/s",
            f"             {'fleet /ws':<14} {_col(t['fleet'], 'msgs_per_s', 0):>26}"
            f"  (lost: {sum(r['dropped'] for r in t['fleet'])})",
            f"             {'mosquitto':<14} {_col(t['mosquitto'], 'msgs_per_s', 0):>26}",
            "",
        ]
    if "command" in out:
        lines += [
            "2. command latency, POST /client/submit_control -> command push read on the"
            " vehicle's /ws/vehicle, ms",
            f"   {'vehicles':>8}  {'median':>26} {'p99':>26}",
        ]
        for r in out["command"]:
            lines.append(
                f"   {r['vehicles']:>8}  {_col(r['runs'], 'median_ms'):>26}"
                f" {_col(r['runs'], 'p99_ms'):>26}"
            )
        last = out["command"][-1]
        med, p99 = _mid(last["runs"], "median_ms"), _mid(last["runs"], "p99_ms")
        lines += [
            f"   at {last['vehicles']}: goal median <= {GOALS['command_median_ms']} ms"
            f" {verdict(med <= GOALS['command_median_ms'])},"
            f" p99 <= {GOALS['command_p99_ms']} ms {verdict(p99 <= GOALS['command_p99_ms'])}",
            "",
        ]
    if "capacity" in out:
        c = out["config"]
        lines += [
            f"3. capacity at 1 Hz telemetry over /ws/vehicle (update_param, one sample, ack"
            f" latency; {c['cap_window_s']:g} s windows after {c['cap_warmup_s']:g} s warm-up;"
            f" load from {c.get('gen_procs', 1)} generator processes, their CPU summed)",
            f"   {'vehicles':>8} {'server cpu %':>16} {'server rss MB':>16}"
            f" {'ack median ms':>20} {'ack p99 ms':>22} {'loadgen cpu %':>16}"
            f" {'acks/s':>20} {'errors':>6}  bound by",
        ]
        for r in out["capacity"]:
            if r.get("skipped"):
                lines.append(f"   {r['vehicles']:>8}  not attempted: the level below was not held")
                continue
            runs = r["runs"]
            lines.append(
                f"   {r['vehicles']:>8} {_col(runs, 'server_cpu_pct', 0):>16}"
                f" {_col(runs, 'server_rss_mb', 0):>16} {_col(runs, 'median_ms', 1):>20}"
                f" {_col(runs, 'p99_ms', 1):>22} {_col(runs, 'loadgen_cpu_pct', 0):>16}"
                f" {_col(runs, 'acks_per_s', 0):>20} {r['errors']:>6}  {r['bound']}"
                + ("" if r["held"] else "  (not held)")
            )
        measured = [r for r in out["capacity"] if not r.get("skipped")]
        held = [r for r in measured if r["held"]]
        top = held[-1] if held else measured[0]
        runs = top["runs"]
        ok = {
            "vehicles": bool(held) and top["vehicles"] >= GOALS["capacity_vehicles"],
            "cpu": max(r["server_cpu_pct"] for r in runs) < GOALS["capacity_cpu_pct"],
            "rss": max(r["server_rss_mb"] for r in runs) <= GOALS["capacity_rss_mb"],
            "median": _mid(runs, "median_ms") <= GOALS["capacity_ack_median_ms"],
            "p99": _mid(runs, "p99_ms") <= GOALS["capacity_ack_p99_ms"],
            "errors": top["errors"] == 0,
        }
        lines += [
            f"   largest level held: {top['vehicles'] if held else 'none'}"
            f" (held: acks/s >= {HELD_FRACTION:.0%} of the vehicles, median ack"
            f" <= {GOALS['capacity_ack_median_ms']:g} ms, no errors)."
            f" Goal {GOALS['capacity_vehicles']:,} vehicles {verdict(ok['vehicles'])};"
            f" at {top['vehicles']}: server under one core {verdict(ok['cpu'])},"
            f" RSS <= {GOALS['capacity_rss_mb']:g} MB {verdict(ok['rss'])},"
            f" median ack <= {GOALS['capacity_ack_median_ms']:g} ms {verdict(ok['median'])},"
            f" p99 <= {GOALS['capacity_ack_p99_ms']:g} ms {verdict(ok['p99'])},"
            f" no errors {verdict(ok['errors'])}",
            "",
        ]
    if "layers" in out:
        d = out["layers"]
        lines += [
            f"4. three-layer route, {d['size']} B, one in flight, ms:"
            " unit -> gateway -> cloud -> operator",
            f"   {'path':<34} {'median':>26} {'p99':>26}",
            f"   {'fleet (unit->relay->/ws/vehicle->/ws/client)':<34}",
            f"   {'':<34} {_col(d['fleet'], 'median_ms'):>26} {_col(d['fleet'], 'p99_ms'):>26}",
            f"   {'mosquitto edge -> bridge -> cloud':<34}"
            f" {_col(d['mosquitto_bridge'], 'median_ms'):>26}"
            f" {_col(d['mosquitto_bridge'], 'p99_ms'):>26}",
            "",
        ]
    return "\n".join(lines)
