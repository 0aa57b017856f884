"""Fleet views: ``/api/*`` answers."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field

from fleet_protocol.common import Sample, Timestamp, WireModel
from fleet_protocol.served import ServedObject, ServedObjects
from fleet_protocol.text import Text
from fleet_protocol.upper import ControlInfo, FailsafePolicy

__all__ = [
    "Alarm",
    "AlarmKind",
    "Event",
    "EventKind",
    "EventList",
    "TelemetryPage",
    "Track",
    "VehicleList",
    "VehicleView",
    "track_coordinates",
    "track_geometry",
]


#: What :class:`Alarm` names (``kind``).
AlarmKind = Literal["failsafe", "no_go_zone", "outside_area", "low_battery"]


class Alarm(WireModel):
    """A condition a vehicle is in now that its crew should see (**extension**): in
    failsafe, inside a no-go zone, outside its operating area, its battery low. The event
    log says when each began (``failsafe_entered``, ``zone_breach``, ``low_battery``)."""

    #: One of :data:`AlarmKind`.
    kind: Text
    message: Text
    zone_id: Text | None = None
    #: Since when it is so: the time of the sample that raised a breach or a low battery,
    #: the time the vehicle says it entered failsafe (None: not known).
    since: Timestamp | None = None


class VehicleView(WireModel):
    vehicle_id: Text
    name: Text
    vehicle_type: Text
    presence: Text
    instance_id: Text | None
    position: Sample | None
    control: ControlInfo | None
    control_mode: Text | None = None
    last_seen: Timestamp | None = None
    #: The vehicle's failsafe policy, and whether the vehicle applies its version.
    failsafe: FailsafePolicy | None = None
    failsafe_acked: bool | None = None
    #: The vehicle's link now: its smoothed one-way delay to the server (its clock
    #: corrected by the offset it estimates) and round trip, in ms (None: not known).
    link_delay_ms: float | None = None
    link_rtt_ms: float | None = None
    #: What is wrong with the vehicle now (**extension**), most urgent first; [] when
    #: nothing is (or the vehicle is offline: nothing is known of it now).
    alarms: list[Alarm] = Field(default_factory=list)


class VehicleList(WireModel):
    vehicles: list[VehicleView]


class Track(WireModel):
    vehicle_id: Text
    points: ServedObjects
    truncated: bool
    next_from: Timestamp | None = None


class TelemetryPage(WireModel):
    samples: ServedObjects
    next_after_seq: int | None


#: Every kind of event the server records (``GET /api/events?kind=``; docs/api.md).
EventKind = Literal[
    "instance",
    "presence",
    "command",
    "control_request",
    "control_grant",
    "control_deny",
    "control_revoke",
    "control_release",
    "control_expired",
    "control_mode",
    "hold_station",
    "failsafe_changed",
    "failsafe_acked",
    "failsafe_entered",
    "failsafe_left",
    "zones_changed",
    "obstacles_changed",
    "zone_breach",
    "zone_cleared",
    "low_battery",
    "battery_recovered",
    "low_battery_cleared",
    "collision_risk",
    "vehicle_changed",
]


class Event(WireModel):
    event_id: Text
    #: One of :data:`EventKind` (``Text``: one an older or newer server recorded is read).
    kind: Text
    vehicle_id: Text | None = None
    instance_id: Text | None = None
    at: Timestamp
    actor: Text | None = None
    data: ServedObject = Field(default_factory=dict)


class EventList(WireModel):
    events: list[Event]
    #: The next page: the same query with ``after`` set to this; null when this page
    #: was not full (there is no more, for now).
    next_after: Text | None = None
    #: The cursor of this page's last event, full or not (null: no event): ``after`` it,
    #: the events recorded since (a client following the log keeps the latest).
    cursor: Text | None = None


def track_geometry(coordinates: list[list[float]]) -> dict[str, Any]:
    """A track's GeoJSON geometry: always a LineString of ``[lon, lat]`` positions (the
    contract's). RFC 7946 asks two positions at least: a track of one point holds it
    twice (a line of no length), a track of none has no coordinates (an empty geometry)."""
    if len(coordinates) == 1:
        coordinates = [coordinates[0], coordinates[0]]
    return {"type": "LineString", "coordinates": coordinates}


def track_coordinates(geometry: dict[str, Any] | None, points: int) -> list[list[float]]:
    """The ``points`` positions of a track's geometry (:func:`track_geometry`'s, or an
    older server's: a Point for one, null for none)."""
    if geometry is None:
        return []
    if geometry["type"] == "Point":
        return [geometry["coordinates"]]
    return list(geometry["coordinates"])[:points]
