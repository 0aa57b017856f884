"""``follow_path`` with ``plan: true``: the server plans round the other vehicles.

The one known kind of obstacle today is another vehicle's latest position,
kept at ``FLEET_SAFETY_RADIUS_M``; the path goes into ``args.path``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from server.domain.planning import NoPath, Obstacle, plan_path
from server.errors import Invalid
from server.services.instances import InstanceState

Planner = Callable[[InstanceState, dict[str, Any], list[InstanceState]], dict[str, Any]]


def vehicle_planner(safety_radius_m: float) -> Planner:
    def plan(
        state: InstanceState, args: dict[str, Any], others: list[InstanceState]
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
            path = plan_path(start, waypoints, obstacles)
        except NoPath as exc:
            raise Invalid(
                f"cannot plan the path: {exc}",
                details=[{"field": "command.args.waypoints", "message": str(exc)}],
            ) from None
        return {**args, "path": [{"lat": lat, "lon": lon} for lat, lon in path]}

    return plan
