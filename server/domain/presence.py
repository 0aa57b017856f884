"""Presence: online -> stale -> offline by heartbeat age; finished for good."""

from __future__ import annotations

from datetime import datetime, timedelta
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


def online_since(now: datetime, stale_after_s: float) -> datetime:
    """The oldest contact that keeps an instance online at ``now`` (:func:`presence_of`'s
    ``stale_after_s``), for a pass over many instances: one subtraction, then
    :func:`is_online` a comparison each."""
    return now - timedelta(seconds=stale_after_s)


def is_online(
    last_seen: datetime | None, since: datetime, *, finished: bool, polling: bool
) -> bool:
    """Whether :func:`presence_of` says ``online``, given :func:`online_since`."""
    if finished:
        return False
    return polling or (last_seen is not None and last_seen >= since)
