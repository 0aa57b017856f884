"""Points in time as people type them: ``10m`` (ten minutes ago), ``2h``, ``1d12h``, ``now``,
or an ISO 8601 time (``2026-11-22T10:00``, no offset meaning UTC); and the wire's times
as a table shows them, narrow (:func:`short_time`, :func:`plain_time`). Pure."""

from __future__ import annotations

import re
from datetime import UTC, datetime, timedelta

from fleet_protocol.common import format_ts, parse_ts

__all__ = ["BadTime", "parse_when", "plain_time", "short_time", "when_text"]

_UNITS = {"s": 1, "m": 60, "h": 3600, "d": 86_400, "w": 604_800}
#: One or more NUMBER+UNIT parts, largest first or not: ``90s``, ``1h30m``, ``1.5h``.
_RELATIVE = re.compile(r"^-?((?:\d+(?:\.\d+)?[smhdw])+)(?:\s*ago)?$")
_PART = re.compile(r"(\d+(?:\.\d+)?)([smhdw])")


class BadTime(ValueError):
    """The text is neither a relative time nor an ISO 8601 one."""


def parse_when(text: str, now: datetime | None = None) -> datetime:
    """The time ``text`` names, in UTC. Relative times count back from ``now`` (the local
    clock by default): ``10m`` is ten minutes ago."""
    now = now or datetime.now(UTC)
    spoken = text.strip().lower()
    if spoken == "now":
        return now
    relative = _RELATIVE.match(spoken.replace(" ", ""))
    if relative:
        seconds = sum(float(n) * _UNITS[u] for n, u in _PART.findall(relative.group(1)))
        try:
            return now - timedelta(seconds=seconds)
        except OverflowError:  # before year 1
            raise BadTime(f"not a time: {text!r} lies before year 1") from None
    try:
        when = datetime.fromisoformat(text.strip().replace("Z", "+00:00").replace("z", "+00:00"))
    except ValueError:
        raise BadTime(
            f"not a time: {text!r} (give 30s, 10m, 2h, 1d, 1h30m, now, or ISO 8601 "
            "like 2026-11-22T10:00:00Z)"
        ) from None
    try:
        return when.replace(tzinfo=UTC) if when.tzinfo is None else when.astimezone(UTC)
    except OverflowError:  # its offset takes it past year 1 or 9999
        raise BadTime(f"not a time: {text!r} lies outside years 1 to 9999 in UTC") from None


def when_text(text: str | None, now: datetime | None = None) -> str | None:
    """``parse_when`` as the wire writes times (ISO 8601 UTC, milliseconds), or None."""
    if text is None:
        return None
    return format_ts(parse_when(text, now))


def plain_time(ts: str | None) -> str:
    """A time of the wire as a record's date: ``2026-11-27T09:29:51.820Z`` is
    ``2026-11-27 09:29:51`` (UTC, to the second); ``-`` for none, and a text that is
    no time as it is."""
    if not ts:
        return "-"
    try:
        return parse_ts(ts).strftime("%Y-%m-%d %H:%M:%S")
    except ValueError:
        return ts


def short_time(ts: str | None, now: datetime | None = None) -> str:
    """A time of the wire as a column of recent things shows it (UTC): ``09:29:51`` today,
    ``11-26 09:29`` on another day of the year, ``2025-11-26`` before; ``-`` for none,
    and a text that is no time as it is."""
    if not ts:
        return "-"
    try:
        when = parse_ts(ts)
    except ValueError:
        return ts
    now = now or datetime.now(UTC)
    if when.date() == now.date():
        return when.strftime("%H:%M:%S")
    return when.strftime("%m-%d %H:%M" if when.year == now.year else "%Y-%m-%d")
