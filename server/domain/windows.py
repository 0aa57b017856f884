"""The time window of a read (a track, a telemetry page, the event log). Pure.

``from`` is inclusive, ``to`` exclusive; a window whose ``from`` is not before
its ``to`` is refused (422 naming ``from``).

A page of the event log carries a cursor, the last event's time and stored id
(``<ISO time>_<24 hex digits>``), so that the next page starts right after it
even when many events share one millisecond, and a cursor whose event has
since been dropped by retention still works.
"""

from __future__ import annotations

import re
from datetime import datetime, timedelta

from fleet_protocol.common import format_ts, parse_ts
from fleet_protocol.values import MAX_TIMESTAMP, MIN_TIMESTAMP
from server.errors import Invalid

__all__ = ["after_cursor", "ordered", "page_cursor", "window"]

_KEY = re.compile("[0-9a-f]{24}")  # a stored id (ObjectId) in hex


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


def page_cursor(at: datetime, key: str) -> str:
    """The cursor of the read's last item: its time and its id."""
    return f"{format_ts(at)}_{key}"


def after_cursor(text: str) -> tuple[datetime, str]:
    """The time and id a cursor of :func:`page_cursor` holds; 422 naming ``after``
    when ``text`` is not one."""
    at, _, key = text.rpartition("_")
    try:
        if not _KEY.fullmatch(key):
            raise ValueError(text)
        when = parse_ts(at)
        if not MIN_TIMESTAMP <= when <= MAX_TIMESTAMP:
            raise ValueError(text)
        return when, key
    except (ValueError, OverflowError):  # OverflowError: a year 1 time in another zone
        raise Invalid(
            "after is not a cursor of this server (a time from 1970 to 2100, '_', 24 hex digits)",
            details=[{"field": "after", "message": "use next_after or cursor of a page"}],
        ) from None
