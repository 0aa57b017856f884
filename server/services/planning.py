"""``follow_path`` with ``plan: true``: the server plans round the other vehicles and
the known fixed obstacles.

Another vehicle's latest position is kept at ``FLEET_SAFETY_RADIUS_M``; a
fixed obstacle (``/api/obstacles``, read by the caller) at its own clearance.
The path goes into ``args.path``.

Planning is CPU work: it runs in threads of its own (:class:`Planning`), at most
``FLEET_PLAN_WORKERS`` at once, so the event loop and the default executor (the
store's journal, password hashing) go on; and one submit plans for at most
``FLEET_PLAN_TIMEOUT_S``. A thread cannot be stopped from outside: the planner
looks at the deadline between its steps and stops itself (``OutOfTime``). A slot
is given back when its thread ends, not when the request does, so a client that
goes away does not leave more planners running than the bound.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from server.domain.plan_frame import Obstacle, Zone
from server.domain.planning import Deadline, NoPath, OutOfTime, plan_path
from server.errors import Invalid, RateLimited
from server.services.instances import InstanceState

Planner = Callable[
    [InstanceState, dict[str, Any], list[InstanceState], Sequence[Zone], Deadline],
    dict[str, Any],
]


def vehicle_planner(safety_radius_m: float) -> Planner:
    def plan(
        state: InstanceState,
        args: dict[str, Any],
        others: list[InstanceState],
        zones: Sequence[Zone],
        deadline: Deadline,
    ) -> dict[str, Any]:
        obstacles = [
            Obstacle(
                float(o.position["lat"]), float(o.position["lon"]), safety_radius_m, o.vehicle_id
            )
            for o in others
            if o.position is not None and not o.finished and safety_radius_m > 0
        ]
        here = state.position
        start = (float(here["lat"]), float(here["lon"])) if here is not None else None
        waypoints = [(float(p["lat"]), float(p["lon"])) for p in args["waypoints"]]
        try:
            path = plan_path(start, waypoints, obstacles, zones, deadline)
        except NoPath as exc:
            # the waypoint refused named as a field (from 0), when one is
            field = "command.args.waypoints"
            if exc.waypoint is not None:
                field += f".{exc.waypoint}"
            raise Invalid(
                f"cannot plan the path: {exc}", details=[{"field": field, "message": str(exc)}]
            ) from None
        return {**args, "path": [{"lat": lat, "lon": lon} for lat, lon in path]}

    return plan


class Planning:
    """Runs a :data:`Planner` off the event loop, within a deadline, a few at once."""

    def __init__(self, planner: Planner, timeout_s: float, workers: int) -> None:
        self.planner = planner
        self.timeout_s = timeout_s
        self.workers = workers
        #: Plans whose thread has not ended yet (at most ``workers``).
        self.running = 0
        self._slots = asyncio.Semaphore(workers)
        self._threads = ThreadPoolExecutor(workers, thread_name_prefix="planner")

    def deadline(self) -> Deadline:
        """The deadline of one submit's planning, from now."""
        return Deadline(time.monotonic() + self.timeout_s, time.monotonic)

    async def plan(
        self,
        state: InstanceState,
        args: dict[str, Any],
        others: list[InstanceState],
        zones: Sequence[Zone],
        deadline: Deadline,
    ) -> dict[str, Any]:
        """``args`` with the planned path: 422 past the deadline, 429 when no planner
        came free before it."""
        try:
            async with asyncio.timeout(max(0.0, deadline.at - time.monotonic())):
                await self._slots.acquire()
        except TimeoutError:
            raise RateLimited(
                f"{self.workers} paths are being planned already (FLEET_PLAN_WORKERS); try again",
                retry_after_s=self.timeout_s,
            ) from None
        loop = asyncio.get_running_loop()
        try:
            job = self._threads.submit(self.planner, state, args, others, zones, deadline)
        except BaseException:
            self._slots.release()
            raise
        self.running += 1
        job.add_done_callback(lambda _: _call_soon(loop, self._ended))
        try:
            return await asyncio.wrap_future(job)
        except OutOfTime:
            why = f"not planned within {self.timeout_s:g} s (FLEET_PLAN_TIMEOUT_S)"
            raise Invalid(
                f"cannot plan the path: {why}; give fewer waypoints, or a path that meets "
                "fewer obstacles",
                details=[{"field": "command.args.waypoints", "message": why}],
            ) from None

    def _ended(self) -> None:
        """A planner thread ended (on the loop)."""
        self.running -= 1
        self._slots.release()


def _call_soon(loop: asyncio.AbstractEventLoop, callback: Callable[[], object]) -> None:
    """From a planner thread: ``callback`` on the loop, unless the loop is gone."""
    try:
        loop.call_soon_threadsafe(callback)
    except RuntimeError:  # the loop closed (the app stopped) while the thread planned
        pass
