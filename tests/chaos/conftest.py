"""The fault runs' scale and their figures.

``make test`` runs them short; ``make chaos`` sets ``FLEET_CHAOS=full`` (the issue's
sizes: 50 agents, ten minutes of a bad link, ...) and ``FLEET_CHAOS_FIGURES`` (a JSON
lines file each run appends its measured figures to; ``python -m tests.chaos.table``
prints them as min / median / max).
"""

from __future__ import annotations

import itertools
import json
import os
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.agent.procs import AgentProcess
from tests.bus.conftest import redis_server  # noqa: F401 (a fixture of these tests too)

FULL = os.environ.get("FLEET_CHAOS") == "full"


def scaled(short: float, full: float) -> float:
    """The short form's size under ``make test``, the full one under ``make chaos``."""
    return full if FULL else short


@pytest.fixture
def agents() -> Iterator[list[AgentProcess]]:
    """Agent processes a test starts; each killed at the end, whatever happened."""
    made: list[AgentProcess] = []
    yield made
    for agent in made:
        agent.kill()


@pytest.fixture
def figures(request: pytest.FixtureRequest) -> Callable[..., None]:
    """``figures(name=value, ...)``: what this run measured, appended to
    ``$FLEET_CHAOS_FIGURES`` (when set) under the test's name, and printed."""
    target = os.environ.get("FLEET_CHAOS_FIGURES")

    def record(**values: float) -> None:
        line = {"test": request.node.name, "at": time.time(), "full": FULL, **values}
        print(json.dumps(line))
        if target:
            with Path(target).open("a") as out:
                out.write(json.dumps(line) + "\n")

    return record


def seq_faults(samples: list[dict[str, Any]], through: int) -> dict[str, Any]:
    """What is wrong with a vehicle's stored samples against seqs 1..through: seqs missing,
    seqs stored more than once, and seqs whose time runs backwards (out of order)."""
    counts: dict[int, int] = {}
    for s in samples:
        counts[s["seq"]] = counts.get(s["seq"], 0) + 1
    ordered = sorted(samples, key=lambda s: s["seq"])
    return {
        "missing": [n for n in range(1, through + 1) if n not in counts][:20],
        "twice": [n for n, c in counts.items() if c > 1][:20],
        "backwards": [b["seq"] for a, b in itertools.pairwise(ordered) if b["ts"] < a["ts"]][:20],
    }
