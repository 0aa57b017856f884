"""What a vehicle's failsafe makes the server do: the command a zone breach sends, and
where the vehicle's home may be. Pure.

A policy with ``on_breach`` makes the server send its action when the vehicle enters a
no-go zone or leaves its operating area (:mod:`server.domain.watch` tells when):
``stop``; ``return_home`` to its home (the policy's, else where its instance first
reported), held there, when the straight way there is clear of its zones; else
``keep_station`` where it is. What the vehicle cannot do is a ``stop``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from fleet_protocol import FailsafePolicy
from server.domain.zones import LatLon, ZoneSet, route_violation
from server.errors import ZoneViolation

__all__ = ["breach_command", "check_home"]


def breach_command(
    policy: FailsafePolicy,
    zones: ZoneSet,
    vehicle_id: str,
    capabilities: Sequence[str],
    position: Mapping[str, Any] | None,
    first_home: LatLon | None,
) -> tuple[str, dict[str, Any]]:
    """The command (type, args) a breach sends under ``policy``, whose action is not
    ``none``. ``position``: the vehicle's latest sample (None: not known);
    ``first_home``: where its instance first reported (None: not known here)."""
    kind, args = "keep_station", {}
    if policy.action == "stop":
        kind = "stop"
    elif policy.action == "return_home":
        home = (policy.home.lat, policy.home.lon) if policy.home is not None else first_home
        start = (float(position["lat"]), float(position["lon"])) if position else None
        if home is not None and route_violation(zones, vehicle_id, start, [home]) is None:
            # There, and held there (keep_station on a point goes to it first).
            kind = "keep_station" if "keep_station" in capabilities else "go_to"
            args = {"lat": home[0], "lon": home[1]}
    if kind not in capabilities and kind != "stop":
        kind, args = "stop", {}
    return kind, args


def check_home(zones: ZoneSet, vehicle_id: str, home: LatLon) -> None:
    """A home the vehicle's zones refuse (in a no-go zone, out of its operating area)
    is 422 naming ``home``: the vehicle drives there itself when its link is lost,
    where no server checks its way."""
    found = route_violation(zones, vehicle_id, None, [home])
    if found is None:
        return
    message = found.message.replace("the target is", "home is")
    refused = ZoneViolation(
        f"the failsafe's {message}", zone_id=found.zone_id, zone=found.name, kind=found.kind
    )
    refused.details = [{"field": "home", "message": message, **refused.zone}]
    raise refused
