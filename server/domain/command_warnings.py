"""What a submit queued as asked does that its sender may not have meant, in words (the
answer's ``warnings``). Pure."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from fleet_protocol import format_ts


def shared_target(
    command_type: str, args: dict[str, Any], vehicles: int, separation_m: float
) -> str | None:
    """What to tell an operator who sends several vehicles to one point, or along one path
    not planned: they meet there. None when the command sends them nowhere in common."""
    if vehicles < 2 or separation_m <= 0:
        return None
    if command_type == "go_to" or (command_type == "keep_station" and "lat" in args):
        where = f"({float(args['lat']):.5f}, {float(args['lon']):.5f})"
        return (
            f"{vehicles} vehicles sent to one point {where}: they will come within "
            f"{separation_m:g} m of each other there; give each its own target to keep them apart"
        )
    if command_type == "follow_path" and not args.get("plan"):
        # Not "plan it": paths planned together are kept apart, so one path planned for
        # several vehicles is refused (its waypoints are in the first vehicle's corridor).
        return (
            f"{vehicles} vehicles sent along one path, not planned: they will come within "
            f"{separation_m:g} m of each other on it; give each its own waypoints, sending "
            "them one at a time"
        )
    return None


def out_of_reach(name: str, presence: str, last_seen: datetime | None, expires: datetime) -> str:
    """What to tell an operator who commands a vehicle that is not online: it waits."""
    seen = f", last heard {format_ts(last_seen)}" if last_seen is not None else ""
    return (
        f"{name} is {presence}{seen}: the command waits for it until {format_ts(expires)} "
        "and expires if it is not back by then"
    )
