"""A submit is all or nothing: the one refusal it answers with, naming each instance
refused and why. Pure."""

from __future__ import annotations

import copy

from server.errors import FleetError, ZoneViolation

__all__ = ["refused"]


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
