"""Guidance: what each command asks of the hull, step by step (pure).

A task looks at the vehicle's state and the estimated current and answers
with a through-water velocity command and how the task stands. Positions
are local east/north metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, Protocol

from vehicle_client.geo import heading_deg
from vehicle_client.sim.dynamics import VehicleParams, VehicleState

TaskStatus = Literal["executing", "done", "failed"]

#: A go_to (and the end of a path) is reached within this distance.
ARRIVE_RADIUS_M = 1.0
#: Proportional gain of the position loops, 1/s: speed asked per metre off.
POSITION_GAIN = 0.25
#: Below this speed the heading is held rather than steered.
MIN_STEER_SPEED_MPS = 0.05


@dataclass(frozen=True)
class Guidance:
    command_ve: float
    command_vn: float
    desired_heading_deg: float | None
    status: TaskStatus
    progress: float | None = None
    detail: str | None = None


class Task(Protocol):
    kind: str

    def guide(
        self, state: VehicleState, current: tuple[float, float], params: VehicleParams
    ) -> Guidance: ...


def water_command(
    dir_e: float,
    dir_n: float,
    speed: float,
    current: tuple[float, float],
    max_speed: float,
) -> tuple[float, float]:
    """Through-water velocity that makes good ``speed`` along ``dir`` over ground.

    Crabs against the current; when the thrusters cannot make ``speed``
    along the line, gives the fastest ground speed along it that they can,
    and when they cannot hold the line at all, pushes straight against the
    part of the current that sets it off.
    """
    norm = math.hypot(dir_e, dir_n)
    ce, cn = current
    if norm == 0.0 or speed <= 0.0:
        we, wn = -ce, -cn
    else:
        ue, un = dir_e / norm, dir_n / norm
        along = ue * ce + un * cn
        disc = along * along - (ce * ce + cn * cn) + max_speed * max_speed
        if disc >= 0.0:
            s = min(speed, along + math.sqrt(disc))
            we, wn = s * ue - ce, s * un - cn
        else:
            we, wn = speed * ue - ce, speed * un - cn
    w = math.hypot(we, wn)
    if w > max_speed:
        we, wn = we * max_speed / w, wn * max_speed / w
    return we, wn


def _steer(we: float, wn: float) -> float | None:
    return heading_deg(we, wn) if math.hypot(we, wn) >= MIN_STEER_SPEED_MPS else None


def _approach(
    state: VehicleState,
    target: tuple[float, float],
    speed: float,
    current: tuple[float, float],
    params: VehicleParams,
) -> tuple[float, float, float]:
    """Water command towards ``target``, slowing in proportion to distance."""
    de, dn = target[0] - state.east, target[1] - state.north
    dist = math.hypot(de, dn)
    we, wn = water_command(de, dn, min(speed, POSITION_GAIN * dist), current, params.max_speed_mps)
    return we, wn, dist


@dataclass
class StopTask:
    """Thrust off and come to rest in the water (the current still carries the hull)."""

    kind: str = "stop"

    def guide(
        self, state: VehicleState, current: tuple[float, float], params: VehicleParams
    ) -> Guidance:
        done = state.water_speed_mps < 0.02
        return Guidance(0.0, 0.0, None, "done" if done else "executing")


@dataclass
class GoToTask:
    target: tuple[float, float]
    speed_mps: float | None = None
    arrive_radius_m: float = ARRIVE_RADIUS_M
    kind: str = "go_to"

    def guide(
        self, state: VehicleState, current: tuple[float, float], params: VehicleParams
    ) -> Guidance:
        speed = self.speed_mps or params.max_speed_mps
        we, wn, dist = _approach(state, self.target, speed, current, params)
        if dist <= self.arrive_radius_m:
            return Guidance(0.0, 0.0, None, "done", detail=f"arrived within {dist:.1f} m")
        return Guidance(we, wn, _steer(we, wn), "executing")


@dataclass
class KeepStationTask:
    """Hold within ``radius_m`` of ``center``; never ends on its own."""

    center: tuple[float, float]
    radius_m: float = 2.0
    kind: str = "keep_station"

    def guide(
        self, state: VehicleState, current: tuple[float, float], params: VehicleParams
    ) -> Guidance:
        we, wn, dist = _approach(state, self.center, params.max_speed_mps, current, params)
        inside = "inside" if dist <= self.radius_m else "outside"
        return Guidance(we, wn, None, "executing", detail=f"{dist:.1f} m off, {inside} radius")


@dataclass
class FollowPathTask:
    """Line-of-sight guidance through ``waypoints`` from where the vehicle starts.

    The vehicle aims at the point ``lookahead_m`` ahead of its projection
    on the current leg, which steers it back onto the line at a rate set
    by the lookahead; a leg is over once the vehicle is within
    ``accept_radius_m`` of its end or past it. Progress is the fraction of
    the whole path length covered.
    """

    waypoints: list[tuple[float, float]]
    speed_mps: float | None = None
    lookahead_m: float = 4.0
    accept_radius_m: float = 2.0
    kind: str = "follow_path"
    _points: list[tuple[float, float]] = field(default_factory=list, init=False)
    _leg: int = field(default=0, init=False)

    def _begin(self, state: VehicleState) -> None:
        self._points = [(state.east, state.north)]
        for p in self.waypoints:
            last = self._points[-1]
            if math.hypot(p[0] - last[0], p[1] - last[1]) > 1e-6:
                self._points.append(p)

    def _leg_lengths(self) -> list[float]:
        pts = self._points
        return [math.dist(pts[i], pts[i + 1]) for i in range(len(pts) - 1)]

    def guide(
        self, state: VehicleState, current: tuple[float, float], params: VehicleParams
    ) -> Guidance:
        if not self._points:
            self._begin(state)
        lengths = self._leg_lengths()
        if not lengths:
            return Guidance(0.0, 0.0, None, "done", progress=1.0)
        speed = self.speed_mps or params.max_speed_mps
        pos = (state.east, state.north)
        while True:
            a, b = self._points[self._leg], self._points[self._leg + 1]
            length = lengths[self._leg]
            te, tn = (b[0] - a[0]) / length, (b[1] - a[1]) / length
            along = (pos[0] - a[0]) * te + (pos[1] - a[1]) * tn
            last_leg = self._leg == len(lengths) - 1
            leg_over = math.dist(pos, b) <= self.accept_radius_m or along >= length
            if last_leg or not leg_over:
                break
            self._leg += 1
        covered = sum(lengths[: self._leg]) + min(max(along, 0.0), length)
        progress = min(1.0, covered / sum(lengths))
        to_end = math.dist(pos, b)
        if last_leg and to_end <= ARRIVE_RADIUS_M:
            return Guidance(0.0, 0.0, None, "done", progress=1.0)
        if last_leg and length - along <= self.lookahead_m:
            we, wn, _ = _approach(state, b, speed, current, params)
        else:
            aim = min(along + self.lookahead_m, length)
            ae, an = a[0] + aim * te - pos[0], a[1] + aim * tn - pos[1]
            we, wn = water_command(ae, an, speed, current, params.max_speed_mps)
        return Guidance(we, wn, _steer(we, wn), "executing", progress=progress)
