"""The simulated vehicle: hull, current, current observer and the active task (pure).

``Simulator.step(dt)`` advances simulated time; nothing here reads a clock.
Commands arrive as the wire's command types and arguments (lat/lon) and
are turned into tasks in the local frame around the start position.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from vehicle_client.geo import LocalFrame
from vehicle_client.sim.dynamics import Current, VehicleParams, VehicleState, step
from vehicle_client.sim.tasks import (
    FollowPathTask,
    GoToTask,
    KeepStationTask,
    StopTask,
    Task,
    TaskStatus,
)

#: Longest physics step; a longer ``dt`` is cut into steps of this size.
MAX_SUBSTEP_S = 0.1
#: Time constant of the current observer, seconds.
CURRENT_OBSERVER_TAU_S = 3.0

CAPABILITIES = ("stop", "go_to", "keep_station", "follow_path")


@dataclass(frozen=True)
class TaskReport:
    kind: str
    status: TaskStatus
    progress: float | None = None
    detail: str | None = None


class Simulator:
    """One omnidirectional surface vehicle, stepped by its owner."""

    def __init__(
        self,
        lat: float,
        lon: float,
        params: VehicleParams | None = None,
        current: Current | None = None,
        battery_pct: float = 100.0,
    ) -> None:
        self.frame = LocalFrame(lat, lon)
        self.params = params or VehicleParams()
        self.current = current or Current()
        self.state = VehicleState(battery_pct=battery_pct)
        self.current_estimate = (0.0, 0.0)
        self.task: Task | None = None
        self.last_report: TaskReport | None = None
        self.elapsed_s = 0.0

    # -- position -------------------------------------------------------
    @property
    def position(self) -> tuple[float, float]:
        return self.frame.to_latlon(self.state.east, self.state.north)

    def distance_to(self, lat: float, lon: float) -> float:
        e, n = self.frame.to_enu(lat, lon)
        return math.hypot(e - self.state.east, n - self.state.north)

    def telemetry(self) -> dict[str, Any]:
        lat, lon = self.position
        return {
            "lat": lat,
            "lon": lon,
            "heading_deg": round(self.state.heading_deg, 2) % 360.0,
            "speed_mps": round(self.state.ground_speed_mps, 3),
            "battery_pct": round(self.state.battery_pct, 3),
        }

    # -- tasks ------------------------------------------------------------
    def task_for(self, kind: str, args: dict[str, Any]) -> Task:
        """A task from a command's type and arguments (already validated)."""
        if kind == "stop":
            return StopTask()
        if kind == "go_to":
            return GoToTask(self.frame.to_enu(args["lat"], args["lon"]), args.get("speed_mps"))
        if kind == "keep_station":
            if args.get("lat") is not None and args.get("lon") is not None:
                center = self.frame.to_enu(args["lat"], args["lon"])
            else:
                center = (self.state.east, self.state.north)
            return KeepStationTask(center, float(args.get("radius_m") or 2.0))
        if kind == "follow_path":
            points = args.get("path") or args["waypoints"]
            enu = [self.frame.to_enu(p["lat"], p["lon"]) for p in points]
            return FollowPathTask(enu, args.get("speed_mps"))
        raise ValueError(f"the simulator cannot execute {kind!r}")

    def start(self, task: Task) -> None:
        self.task = task
        self.last_report = None

    def clear(self) -> None:
        """Drop the active task: thrust off, without reporting anything."""
        self.task = None

    # -- time ---------------------------------------------------------------
    def step(self, dt: float) -> TaskReport | None:
        """Advance ``dt`` simulated seconds; the active task's report, if any."""
        remaining = dt
        while remaining > 1e-12:
            h = min(MAX_SUBSTEP_S, remaining)
            remaining -= h
            self._substep(h)
        return self.last_report

    def _substep(self, dt: float) -> None:
        if self.task is not None:
            g = self.task.guide(self.state, self.current_estimate, self.params)
            self.last_report = TaskReport(self.task.kind, g.status, g.progress, g.detail)
            if g.status != "executing":
                self.task = None
            ce, cn, heading = g.command_ve, g.command_vn, g.desired_heading_deg
        else:
            ce, cn, heading = 0.0, 0.0, None
        new = step(self.state, self.params, ce, cn, heading, self.current, dt)
        self._observe_current(new, dt)
        self.state = new
        self.elapsed_s += dt

    def _observe_current(self, new: VehicleState, dt: float) -> None:
        """Estimate the current as ground velocity minus water velocity, low-passed.

        A real vehicle gets its ground velocity from GNSS and its water
        velocity from its thrust model; here both are exact, the filter lag
        is what the controllers have to live with.
        """
        meas_e = new.ground_ve - new.water_ve
        meas_n = new.ground_vn - new.water_vn
        k = dt / (CURRENT_OBSERVER_TAU_S + dt)
        ee, en = self.current_estimate
        self.current_estimate = (ee + k * (meas_e - ee), en + k * (meas_n - en))

    def drain(self, pct: float) -> None:
        """Set the battery level (for scenarios and tests)."""
        self.state = replace(self.state, battery_pct=max(0.0, min(100.0, pct)))
