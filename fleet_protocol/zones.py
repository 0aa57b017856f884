"""Operating areas and no-go zones (``/api/zones``).

A ``no_go`` zone is refused to every vehicle (or, when ``vehicles`` lists some, to
those): a target in it, or a route through it, is a 422 naming the zone, and a planned
path goes round it (at ``clearance_m``). An ``operating_area`` holds the vehicles it
lists: a target or route outside every area of a vehicle is refused. Telemetry entering
a no-go zone or leaving an area raises an event. The set of zones has a ``version`` that
rises with each change: a command checked against an older one is checked again before
it is handed out.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import ConfigDict, Field, StrictFloat, field_validator

from fleet_protocol.common import Identifier, Timestamp, WireModel, refuse_null
from fleet_protocol.obstacles import PolygonGeometry
from fleet_protocol.text import Label, Text

__all__ = [
    "CreateZone",
    "PatchZone",
    "ZoneChange",
    "ZoneChanges",
    "ZoneKind",
    "ZoneList",
    "ZoneView",
]

ZoneKind = Literal["no_go", "operating_area"]


class _ZoneBody(WireModel):
    """A zone's body: a field it does not know is a 422 naming it (``clearance`` for
    ``clearance_m``, ``vehicle`` for ``vehicles``: a no-go zone would otherwise hold every
    vehicle, at the default clearance). The fields a zone is read with that no body sets
    are taken and ignored: a client may send back the zone it read."""

    model_config = ConfigDict(extra="forbid")

    zone_id: Any = Field(default=None, exclude=True, description="ignored (the zone as read)")
    version: Any = Field(default=None, exclude=True, description="ignored (the zone as read)")
    created_at: Any = Field(default=None, exclude=True, description="ignored (the zone as read)")
    updated_at: Any = Field(default=None, exclude=True, description="ignored (the zone as read)")


class CreateZone(_ZoneBody):
    name: Label = Field(min_length=1, max_length=128)
    kind: ZoneKind
    polygon: PolygonGeometry
    #: The vehicles it applies to; empty: every vehicle (a no-go zone only: an operating
    #: area holds the vehicles it lists).
    vehicles: list[Identifier] = Field(default_factory=list, max_length=1000)
    clearance_m: StrictFloat | None = Field(
        default=None,
        ge=0,
        le=10_000,
        allow_inf_nan=False,
        description="how far a planned path keeps from a no-go zone; unset: FLEET_SAFETY_RADIUS_M",
    )


class PatchZone(_ZoneBody):
    """The fields to change; one left out is kept (``null`` is a 422 naming it). A patch
    that changes nothing leaves the zone, its version and ``updated_at`` as they are."""

    #: Only the zone's own kind is taken (a client may send back the zone it read): a
    #: zone's kind cannot change, another is a 422 naming ``kind``.
    kind: ZoneKind | None = Field(
        default=None,
        description="the zone's own kind, or left out: a zone's kind cannot change "
        "(delete it and create another); another kind is a 422",
    )
    name: Label | None = Field(default=None, min_length=1, max_length=128)
    polygon: PolygonGeometry | None = None
    vehicles: list[Identifier] | None = Field(default=None, max_length=1000)
    clearance_m: StrictFloat | None = Field(default=None, ge=0, le=10_000, allow_inf_nan=False)

    _no_null = field_validator("kind", "name", "polygon", "vehicles", "clearance_m", mode="before")(
        refuse_null
    )


class ZoneView(WireModel):
    zone_id: Text
    name: Text
    kind: ZoneKind
    polygon: PolygonGeometry
    vehicles: list[Text]
    clearance_m: float
    #: The set's version when this zone last changed.
    version: int
    created_at: Timestamp
    updated_at: Timestamp


class ZoneList(WireModel):
    zones: list[ZoneView]
    #: The version of the whole set (it rises with every change).
    version: int


class ZoneChange(WireModel):
    """One change of a zone the caller sees (**extension**): when, the set's version it
    made, and whether it removed the zone."""

    at: Timestamp
    version: int
    zone_id: Text
    deleted: bool


class ZoneChanges(WireModel):
    """``GET /api/zones/changes``: the changes in a window, oldest first (a replay reads
    the set again after each: ``GET /api/zones?at=``)."""

    changes: list[ZoneChange]
