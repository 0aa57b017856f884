"""The time window of a read (a track, a telemetry page, the event log). Pure.

``from`` is inclusive, ``to`` exclusive; a window whose ``from`` is not before
its ``to`` is refused (422 naming ``from``).
"""

from __future__ import annotations

from datetime import datetime, timedelta

from server.errors import Invalid

__all__ = ["ordered", "window"]


def ordered(start: datetime | None, end: datetime | None) -> None:
    """Refuse ``from`` and ``to`` both given, ``from`` not before ``to``."""
    if start is not None and end is not None and start >= end:
        raise Invalid(
            "from must come before to",
            details=[{"field": "from", "message": "must be earlier than to"}],
        )


def window(
    start: datetime | None, end: datetime | None, now: datetime, span: timedelta
) -> tuple[datetime, datetime]:
    """The window with its defaults: ``to`` now, ``from`` ``span`` before ``to``; refused
    as :func:`ordered` says once they are filled in."""
    end = end or now
    start = start or end - span
    ordered(start, end)
    return start, end
