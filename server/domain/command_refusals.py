"""A submit is all or nothing: the one refusal it answers with, naming each instance
refused and why. Pure."""

from __future__ import annotations

import copy

from server.errors import FleetError, ZoneViolation

__all__ = ["refused"]


def _fields(exc: FleetError) -> dict[str, list[str]]:
    """The command's fields a refusal is about (``command.args.waypoints.1``: the second
    waypoint a path cannot be planned through), as its own details name them."""
    named = [d["field"] for d in exc.details or [] if isinstance(d, dict) and "field" in d]
    return {"fields": named} if named else {}


def refused(refusals: list[tuple[int, str, FleetError]], asked: int) -> FleetError:
    """All or nothing: the first refusal's status, and every refusal in ``details``."""
    refusals.sort(key=lambda r: r[0])
    first = refusals[0][2]
    details = [
        {
            "field": f"instance_ids.{index}",
            "instance_id": instance_id,
            "code": exc.code,
            "message": exc.message,
            **(exc.zone if isinstance(exc, ZoneViolation) else {}),
            **_fields(exc),
        }
        for index, instance_id, exc in refusals
    ]
    message = (
        first.message
        if asked == 1
        else f"{len(refusals)} of {asked} instances refused ({first.message}); nothing queued"
    )
    error = copy.copy(first)  # same class, status and Retry-After
    error.message, error.details, error.args = message, details, (message,)
    return error
