"""Presence: online -> stale -> offline by heartbeat age; finished for good."""

from __future__ import annotations

from datetime import datetime
from typing import Literal

Presence = Literal["online", "stale", "offline", "finished"]


def presence_of(
    last_seen: datetime | None,
    now: datetime,
    *,
    stale_after_s: float,
    offline_after_s: float,
    finished: bool = False,
    polling: bool = False,
) -> Presence:
    """The presence an instance has at ``now``.

    An open long poll counts as contact for as long as it is open.
    """
    if finished:
        return "finished"
    if polling:
        return "online"
    if last_seen is None:
        return "offline"
    age = (now - last_seen).total_seconds()
    if age <= stale_after_s:
        return "online"
    if age <= offline_after_s:
        return "stale"
    return "offline"
