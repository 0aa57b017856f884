"""The planner runner (``server.services.planning.Planning``) with a planner the test
holds: a bound on plans at once (429 past the deadline), a deadline the planner keeps
(422), and a slot held until its thread ends."""

from __future__ import annotations

import asyncio
import math
import threading
from typing import Any

import pytest

from server.domain.planning import Deadline
from server.errors import Invalid, RateLimited
from server.services.planning import Planning
from tests.server.commanding import eventually

NO_DEADLINE = Deadline(math.inf, lambda: 0.0)


def held_until(release: threading.Event) -> Any:
    """A planner that works until ``release`` is set, looking at its deadline."""

    def plan(state: Any, args: Any, others: Any, zones: Any, deadline: Deadline) -> Any:
        while not release.wait(0.01):
            deadline.check()
        return {"planned": True}

    return plan


async def running(planning: Planning, count: int) -> None:
    async def check() -> bool:
        return planning.running == count

    await eventually(check)


async def plan(planning: Planning, deadline: Deadline) -> dict[str, Any]:
    return await planning.plan(None, {}, [], (), deadline)  # type: ignore[arg-type]


async def test_a_submit_that_finds_every_planner_busy_until_its_deadline_is_429() -> None:
    release = threading.Event()
    planning = Planning(held_until(release), timeout_s=0.3, workers=1)
    first = asyncio.create_task(plan(planning, NO_DEADLINE))
    try:
        await running(planning, 1)
        with pytest.raises(RateLimited, match="FLEET_PLAN_WORKERS") as busy:
            await plan(planning, planning.deadline())
        assert busy.value.retry_after_s == 0.3
    finally:
        release.set()
    assert await first == {"planned": True}
    await running(planning, 0)


async def test_past_its_deadline_the_planner_stops_itself_and_it_is_422() -> None:
    planning = Planning(held_until(threading.Event()), timeout_s=0.2, workers=1)
    with pytest.raises(Invalid, match="FLEET_PLAN_TIMEOUT_S") as late:
        await plan(planning, planning.deadline())
    why = "not planned within 0.2 s (FLEET_PLAN_TIMEOUT_S)"
    assert late.value.details == [{"field": "command.args.waypoints", "message": why}]
    await running(planning, 0)


async def test_a_client_that_goes_away_holds_its_slot_until_its_thread_ends() -> None:
    release = threading.Event()
    planning = Planning(held_until(release), timeout_s=5, workers=1)
    gone = asyncio.create_task(plan(planning, NO_DEADLINE))
    await running(planning, 1)
    gone.cancel()
    with pytest.raises(asyncio.CancelledError):
        await gone
    assert planning.running == 1  # its thread still plans: no second one starts meanwhile
    with pytest.raises(RateLimited):
        await plan(planning, Deadline(0.0, lambda: 0.0))
    release.set()
    await running(planning, 0)
