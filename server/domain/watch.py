"""What the server watches in each vehicle's telemetry: zone breaches and a low battery.
Pure.

A vehicle's watch state is the set of zones it is in breach of (a no-go zone it is
inside, ``area:<vehicle>`` when it is outside every operating area of its own) and
whether its battery is low. Each new position gives the next state; what changed
between the two is what gets an event. The battery is low below the vehicle's threshold
and stays low until it is :data:`BATTERY_HYSTERESIS_PCT` above it again, so that a
reading that wavers round the threshold raises one event, not one a second.

Each breach and a low battery carry since when (``since``, the time of the sample that
raised them): dated when the state moves (:func:`dated`), kept while they last. Two
states are equal by what they hold, not by their dates.

The rules change too: a zone drawn, changed or deleted, a threshold set or lifted. The
latest position is then judged again by the new rules, and what ends so is told for
what it is: a zone that no longer applies (:func:`cleared_data`), a low battery whose
threshold moved (``low_battery_cleared``, :func:`battery_event`), not a recovery.

Each replica judges by the rules as it last read them, and another may have read newer
ones: a stored state names the rules it was judged by (:class:`RulesSeen`, the zones'
version and the vehicle's policy version), and a judgement by older rules
(:func:`behind`) is not written over it; it would bring back what the newer rules ended.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any, NamedTuple

from fleet_protocol import EventKind, FailsafePolicy
from server.domain.alarms import HYSTERESIS_PCT
from server.domain.zones import LatLon, ZoneSet, breaches

#: Points above the threshold the battery must come back to before it is no longer low.
BATTERY_HYSTERESIS_PCT = HYSTERESIS_PCT


@dataclass(frozen=True)
class WatchState:
    breaches: frozenset[str] = frozenset()
    low_battery: bool = False
    #: zone id -> since when it is breached (absent: not known, as in a state stored
    #: before dates were kept)
    breach_since: Mapping[str, datetime] = field(default_factory=dict, compare=False)
    battery_since: datetime | None = field(default=None, compare=False)


class RulesSeen(NamedTuple):
    """The rules a watch state was judged by: the zones' version, the policy's version
    (0 and 0 in a state stored before they were kept)."""

    zones: int = 0
    policy: int = 0


def behind(mine: RulesSeen, stored: RulesSeen) -> bool:
    """Whether rules ``mine`` are older than those ``stored`` was judged by (either
    version lower): a judgement by them must not replace it."""
    return mine.zones < stored.zones or mine.policy < stored.policy


@dataclass(frozen=True)
class Change:
    """What moved between two watch states."""

    entered: frozenset[str] = field(default_factory=frozenset)
    left: frozenset[str] = field(default_factory=frozenset)
    battery: str | None = None  # "low" or "recovered"

    def __bool__(self) -> bool:
        return bool(self.entered or self.left or self.battery)


def battery_low(was_low: bool, battery_pct: float | None, threshold: float | None) -> bool:
    if threshold is None or battery_pct is None:
        return was_low and threshold is not None  # no reading: as it was
    if was_low:
        return battery_pct < threshold + BATTERY_HYSTERESIS_PCT
    return battery_pct < threshold


def next_state(
    was: WatchState,
    zones: ZoneSet,
    vehicle_id: str,
    point: LatLon,
    battery_pct: float | None,
    threshold: float | None,
) -> WatchState:
    now = breaches(zones, vehicle_id, point)
    low = battery_low(was.low_battery, battery_pct, threshold)
    if low == was.low_battery and now == was.breaches:
        return was  # as it was (most samples): no new state
    return WatchState(now, low)


class Judged(NamedTuple):
    """What one judgement of the watch was made on: the position, its battery reading, the
    time a new alarm is dated by, and which rules moved (``zones_moved``,
    ``threshold_moved``: what changes by them is told so; neither: a new
    sample came)."""

    lat: float
    lon: float
    battery_pct: float | None
    at: datetime
    zones_moved: bool = False
    threshold_moved: bool = False

    @property
    def point(self) -> tuple[float, float]:
        return (self.lat, self.lon)


class JudgedBy(NamedTuple):
    """The rules one judgement is made by, as this replica has them: the zones and the
    vehicle's policy (its battery threshold)."""

    zones: ZoneSet
    policy: FailsafePolicy

    @property
    def seen(self) -> RulesSeen:
        return RulesSeen(self.zones.version, self.policy.version)

    def next(self, was: WatchState, vehicle_id: str, judged: Judged) -> WatchState:
        """The state after ``was`` for the judged position and reading."""
        threshold = self.policy.low_battery_pct
        return next_state(was, self.zones, vehicle_id, judged.point, judged.battery_pct, threshold)


class Rules(NamedTuple):
    """What the watch judges by: the zones, and each vehicle's battery threshold (those
    with a policy of their own; the others have the default's)."""

    zones: ZoneSet
    thresholds: dict[str, float | None]


def change(was: WatchState, now: WatchState) -> Change:
    battery = None
    if now.low_battery != was.low_battery:
        battery = "low" if now.low_battery else "recovered"
    return Change(now.breaches - was.breaches, was.breaches - now.breaches, battery)


def dated(was: WatchState, now: WatchState, at: datetime) -> WatchState:
    """``now`` with its dates: what ``was`` held already keeps its own; what is new is
    dated ``at`` (the time of the sample that raised it); what ended has none."""
    breach_since = {
        z: was.breach_since.get(z) if z in was.breaches else at for z in sorted(now.breaches)
    }
    battery_since = None
    if now.low_battery:
        battery_since = was.battery_since if was.low_battery else at
    return WatchState(
        now.breaches,
        now.low_battery,
        {z: t for z, t in breach_since.items() if t is not None},
        battery_since,
    )


def breach_data(zones: ZoneSet, vehicle_id: str, zone_id: str, *, entered: bool) -> dict[str, Any]:
    """How a zone the vehicle ``entered`` (or left) is named in its events and alarms: its
    id, name and kind, and what happened. ``area:<vehicle>`` stands for all of its
    operating areas (it is outside every one)."""
    if zone_id.startswith("area:"):
        areas = zones.of(vehicle_id)[1]
        return {
            "zone_id": areas[0].zone_id if areas else None,
            "zone": ", ".join(a.name for a in areas),
            "zone_kind": "operating_area",
            "message": "left its operating area" if entered else "back in its operating area",
        }
    area = next((a for a in zones.areas if a.zone_id == zone_id), None)
    name = area.name if area else zone_id
    return {
        "zone_id": zone_id,
        "zone": name,
        "zone_kind": "no_go",
        "message": f"{'entered' if entered else 'left'} no-go zone {name}",
    }


def _has(zones: ZoneSet, vehicle_id: str, zone_id: str) -> bool:
    """Whether the set holds the zone for the vehicle (``area:``: any area of its own)."""
    no_go, areas = zones.of(vehicle_id)
    if zone_id.startswith("area:"):
        return bool(areas)
    return any(a.zone_id == zone_id for a in no_go)


def cleared_data(sets: Sequence[ZoneSet], vehicle_id: str, zone_id: str) -> dict[str, Any]:
    """How a zone the vehicle is no longer in breach of is named in its ``zone_cleared``.
    ``sets``: the set now first, then those judged by before, newest first. A zone the set
    now still holds for the vehicle: it left it (:func:`breach_data`); one it no longer
    holds (deleted, or no longer the vehicle's) is named by the newest set that did, and
    the message says that it no longer applies."""
    now = sets[0]
    if _has(now, vehicle_id, zone_id):
        return breach_data(now, vehicle_id, zone_id, entered=False)
    named_by = next((z for z in sets[1:] if _has(z, vehicle_id, zone_id)), now)
    data = breach_data(named_by, vehicle_id, zone_id, entered=False)
    what = "its operating area" if data["zone_kind"] == "operating_area" else "no-go zone"
    data["message"] = " ".join(p for p in (what, data["zone"], "no longer applies") if p)
    return data


def battery_event(
    moved: str, reading: float | None, threshold: float | None, *, rule: bool
) -> EventKind:
    """The event kind of a battery watch that ``moved`` (``low``, ``recovered``): a low
    battery ends as ``battery_recovered`` only when the reading came back above the
    threshold; ended by the threshold itself (lifted, or moved: ``rule``), it is
    ``low_battery_cleared``."""
    if moved == "low":
        return "low_battery"
    if rule or threshold is None or reading is None:
        return "low_battery_cleared"
    return "battery_recovered"
