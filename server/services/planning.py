"""``follow_path`` with ``plan: true``: the server plans round the other vehicles and
the known fixed obstacles.

Another vehicle's latest position is kept at ``FLEET_SAFETY_RADIUS_M``; a
fixed obstacle (``/api/obstacles``, read by the caller) at its own clearance.
The path goes into ``args.path``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from server.domain.planning import NoPath, Obstacle, Zone, plan_path
from server.errors import Invalid
from server.services.instances import InstanceState

Planner = Callable[
    [InstanceState, dict[str, Any], list[InstanceState], Sequence[Zone]], dict[str, Any]
]


def vehicle_planner(safety_radius_m: float) -> Planner:
    def plan(
        state: InstanceState,
        args: dict[str, Any],
        others: list[InstanceState],
        zones: Sequence[Zone],
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
            path = plan_path(start, waypoints, obstacles, zones)
        except NoPath as exc:
            raise Invalid(
                f"cannot plan the path: {exc}",
                details=[{"field": "command.args.waypoints", "message": str(exc)}],
            ) from None
        return {**args, "path": [{"lat": lat, "lon": lon} for lat, lon in path]}

    return plan
