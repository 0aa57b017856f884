"""Hull dynamics: an omnidirectional surface vehicle in a water current.

The thrusters push the hull through the water in any direction (the
H2OmniX has vectored thrust, so course and heading are independent); the
water itself moves with the current, so the ground velocity is the
through-water velocity plus the current. The through-water velocity follows
the command with a bounded acceleration and saturates at the top speed.
The battery drains a little at rest and more with the thrust used.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from vehicle_client.geo import wrap_deg


@dataclass(frozen=True)
class VehicleParams:
    max_speed_mps: float = 0.5
    accel_mps2: float = 0.25
    turn_rate_dps: float = 45.0
    #: Battery drain at rest (electronics) and at full thrust, percent per hour.
    idle_drain_pct_h: float = 1.0
    full_thrust_drain_pct_h: float = 12.0

    def __post_init__(self) -> None:
        if self.max_speed_mps <= 0 or self.accel_mps2 <= 0 or self.turn_rate_dps <= 0:
            raise ValueError("max_speed_mps, accel_mps2 and turn_rate_dps must be positive")


@dataclass(frozen=True)
class Current:
    """A uniform water current, metres per second towards east and north."""

    east_mps: float = 0.0
    north_mps: float = 0.0

    @classmethod
    def from_speed(cls, speed_mps: float, towards_deg: float) -> Current:
        rad = math.radians(towards_deg)
        return cls(speed_mps * math.sin(rad), speed_mps * math.cos(rad))


@dataclass(frozen=True)
class VehicleState:
    east: float = 0.0
    north: float = 0.0
    #: Velocity through the water (what the thrusters make).
    water_ve: float = 0.0
    water_vn: float = 0.0
    heading_deg: float = 0.0
    battery_pct: float = 100.0
    #: Ground velocity of the last step (water velocity plus current).
    ground_ve: float = 0.0
    ground_vn: float = 0.0

    @property
    def ground_speed_mps(self) -> float:
        return math.hypot(self.ground_ve, self.ground_vn)

    @property
    def water_speed_mps(self) -> float:
        return math.hypot(self.water_ve, self.water_vn)


def _limit(ve: float, vn: float, bound: float) -> tuple[float, float]:
    norm = math.hypot(ve, vn)
    if norm <= bound or norm == 0.0:
        return ve, vn
    return ve * bound / norm, vn * bound / norm


def step(
    state: VehicleState,
    params: VehicleParams,
    command_ve: float,
    command_vn: float,
    desired_heading_deg: float | None,
    current: Current,
    dt: float,
) -> VehicleState:
    """Advance ``dt`` seconds with a through-water velocity command.

    ``desired_heading_deg`` ``None`` holds the heading. An empty battery
    gives no thrust: the hull slows down and drifts with the current.
    """
    if dt <= 0:
        return state
    if state.battery_pct <= 0.0:
        command_ve, command_vn = 0.0, 0.0
    command_ve, command_vn = _limit(command_ve, command_vn, params.max_speed_mps)
    dve, dvn = _limit(
        command_ve - state.water_ve, command_vn - state.water_vn, params.accel_mps2 * dt
    )
    water_ve, water_vn = state.water_ve + dve, state.water_vn + dvn

    heading = state.heading_deg
    if desired_heading_deg is not None:
        turn = wrap_deg(desired_heading_deg - heading)
        max_turn = params.turn_rate_dps * dt
        heading = (heading + max(-max_turn, min(max_turn, turn))) % 360.0

    ground_ve, ground_vn = water_ve + current.east_mps, water_vn + current.north_mps
    # Trapezoid on the through-water part keeps the step accurate at coarse dt.
    east = state.east + (state.water_ve + water_ve) / 2 * dt + current.east_mps * dt
    north = state.north + (state.water_vn + water_vn) / 2 * dt + current.north_mps * dt

    thrust = min(1.0, math.hypot(water_ve, water_vn) / params.max_speed_mps)
    drain_h = params.idle_drain_pct_h + params.full_thrust_drain_pct_h * thrust**2
    battery = max(0.0, state.battery_pct - drain_h * dt / 3600.0)
    return replace(
        state,
        east=east,
        north=north,
        water_ve=water_ve,
        water_vn=water_vn,
        heading_deg=heading,
        battery_pct=battery,
        ground_ve=ground_ve,
        ground_vn=ground_vn,
    )
