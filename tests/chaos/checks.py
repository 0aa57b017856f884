"""What the fault runs share: an agent pointed at a proxy, the delivery probes and the
final check of a vehicle's stored telemetry (every seq once, in order)."""

from __future__ import annotations

import time
from types import SimpleNamespace
from typing import Any

from tests.agent.procs import Fleet
from tests.chaos.conftest import seq_faults


def via(url: str) -> Any:
    """What ``AgentProcess`` needs of a server: its URL (here, a proxy's)."""
    return SimpleNamespace(url=url)


def stored_through(fleet: Fleet, vehicle_id: str) -> int:
    samples = fleet.telemetry(vehicle_id)
    return max((s["seq"] for s in samples), default=0)


def has_stored(fleet: Fleet, vehicle_id: str, seq: int) -> bool:
    """Whether a sample at or past ``seq`` is stored (one page of one sample: the probe
    stays cheap however much is stored)."""
    page = fleet.call(
        "GET",
        f"/api/vehicles/{vehicle_id}/telemetry",
        params={"after_seq": max(0, seq - 1), "limit": 1},
    )
    return bool(page["samples"])


def assert_exactly_once(fleet: Fleet, vehicle_id: str, through: int) -> int:
    """Every seq 1..through stored once (and every seq after it that is stored), in time
    order; how many samples are stored."""
    samples = fleet.telemetry(vehicle_id)
    faults = seq_faults(samples, max([through, *(s["seq"] for s in samples)]))
    assert faults == {"missing": [], "twice": [], "backwards": []}, (vehicle_id, faults)
    return len(samples)


def hold(seconds: float) -> None:
    """Let the fault (or the good spell) last: the thing under test is the other
    processes, which run meanwhile; nothing here waits on them."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        time.sleep(0.05)
