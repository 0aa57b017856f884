"""Commands (missions): their types, arguments, life cycle and wire object."""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence
from typing import Literal, get_args

from pydantic import (
    ConfigDict,
    Field,
    StrictBool,
    StrictFloat,
    ValidationError,
    model_validator,
)

from fleet_protocol.common import Latitude, LatLon, Longitude, Timestamp, WireModel
from fleet_protocol.served import ServedObject
from fleet_protocol.text import Text
from fleet_protocol.values import JsonObject

__all__ = [
    "ACK_STATUSES",
    "ARGS_MODELS",
    "COMMAND_TYPES",
    "FINAL_STATUSES",
    "MOTION_TYPES",
    "SERVER_ARGS",
    "CommandObject",
    "CommandSpec",
    "CommandStatus",
    "CommandType",
    "FollowPathArgs",
    "GoToArgs",
    "HistoryEntry",
    "KeepStationArgs",
    "StopArgs",
    "path_hash",
    "route_of",
]

CommandType = Literal["stop", "go_to", "keep_station", "follow_path"]
COMMAND_TYPES: tuple[str, ...] = get_args(CommandType)
MOTION_TYPES = frozenset({"go_to", "keep_station", "follow_path"})

CommandStatus = Literal[
    "queued",
    "delivered",
    "accepted",
    "executing",
    "done",
    "rejected",
    "failed",
    "expired",
    "cancelled",
]
FINAL_STATUSES = frozenset({"done", "rejected", "failed", "expired", "cancelled"})
#: Statuses a vehicle may report in an ack.
ACK_STATUSES = ("accepted", "executing", "done", "rejected", "failed")

MAX_WAYPOINTS = 1000


class StopArgs(WireModel):
    pass


class GoToArgs(WireModel):
    lat: Latitude
    lon: Longitude
    speed_mps: StrictFloat | None = Field(default=None, gt=0, le=50, allow_inf_nan=False)


class KeepStationArgs(WireModel):
    lat: Latitude | None = None
    lon: Longitude | None = None
    radius_m: StrictFloat = Field(default=2.0, gt=0, le=10_000, allow_inf_nan=False)

    @model_validator(mode="after")
    def _both_or_neither(self) -> KeepStationArgs:
        if (self.lat is None) != (self.lon is None):
            raise ValueError("give both lat and lon, or neither (then: where the vehicle is)")
        return self


class FollowPathArgs(WireModel):
    waypoints: list[LatLon] = Field(min_length=1, max_length=MAX_WAYPOINTS)
    speed_mps: StrictFloat | None = Field(default=None, gt=0, le=50, allow_inf_nan=False)
    plan: StrictBool = False
    #: The planned path, filled in by the server when ``plan`` is true.
    path: list[LatLon] | None = None
    #: The hash of the route the vehicle is to follow (``path`` if planned, else the
    #: waypoints), filled in by the server (:func:`path_hash`). The vehicle acknowledges
    #: the hash of what it stored before it starts; another one is never run.
    path_hash: Text | None = Field(default=None, max_length=128)


def path_hash(points: Sequence[Mapping[str, float] | LatLon]) -> str:
    """The hash of a route: SHA-256 of its positions at 1e-7 degree (about 1 cm), so
    that the server and the vehicle agree on it whatever JSON did to the floats."""
    digest = hashlib.sha256()
    for point in points:
        lat, lon = (
            (point["lat"], point["lon"]) if isinstance(point, Mapping) else (point.lat, point.lon)
        )
        digest.update(f"{round(float(lat) * 1e7)},{round(float(lon) * 1e7)};".encode())
    return "sha256:" + digest.hexdigest()


def route_of(args: Mapping[str, object]) -> list[Mapping[str, float]]:
    """The positions a ``follow_path`` drives: its planned ``path``, else its waypoints."""
    route = args.get("path") or args.get("waypoints") or []
    return list(route)  # type: ignore[call-overload]


ARGS_MODELS: dict[str, type[WireModel]] = {
    "stop": StopArgs,
    "go_to": GoToArgs,
    "keep_station": KeepStationArgs,
    "follow_path": FollowPathArgs,
}

#: The args of a type that are the server's alone: it fills them in (``path`` when it
#: plans, ``path_hash`` over what the vehicle drives), so a submit may not carry them.
SERVER_ARGS: dict[str, dict[str, str]] = {
    "follow_path": {
        "path": "the path is filled in by the server, never sent: give waypoints "
        "(with plan: true the server plans the path)",
        "path_hash": "the path hash is filled in by the server over the route the vehicle "
        "drives, never sent",
    },
}


class CommandSpec(WireModel):
    """What an operator asks for: ``{type, args, max_drift_m?}``."""

    # A field it does not know is a 422 naming it, not dropped: ``max_drift`` for
    # ``max_drift_m`` would send the command with no drift guard, unsaid.
    model_config = ConfigDict(extra="forbid")

    type: CommandType
    #: Checked as a free-form object first, then by the type's model (``ARGS_MODELS``).
    args: JsonObject = Field(default_factory=dict)
    max_drift_m: StrictFloat | None = Field(default=None, gt=0, le=1_000_000, allow_inf_nan=False)

    @model_validator(mode="after")
    def _validate_args(self) -> CommandSpec:
        # The server's own args (SERVER_ARGS) are refused, whatever their value: what the
        # vehicle drives, and what the zones are checked against, is the server's.
        theirs = SERVER_ARGS.get(self.type, {})
        refused = [f"args.{name}: {why}" for name, why in theirs.items() if name in self.args]
        model = ARGS_MODELS[self.type]
        # An argument the type does not take is refused, not dropped: ``speed`` for
        # ``speed_mps`` would run at the vehicle's own speed, unsaid. (A vehicle reading a
        # command still ignores what it does not know: ARGS_MODELS stay lenient.)
        takes = [name for name in model.model_fields if name not in theirs]
        refused += [
            f"args.{name}: {self.type} takes no {name!r} (it takes "
            + (", ".join(takes) if takes else "no arguments")
            + ")"
            for name in self.args
            if name not in model.model_fields
        ]
        try:
            parsed = model.model_validate({k: v for k, v in self.args.items() if k not in theirs})
        except ValidationError as exc:
            # Re-raise with field paths under ``args`` so a 422 names them.
            raise ValueError("; ".join([*refused, _args_message(exc)])) from None
        if refused:
            raise ValueError("; ".join(refused))
        self.args = parsed.model_dump(exclude_none=True)
        return self

    def parsed_args(self) -> WireModel:
        return ARGS_MODELS[self.type].model_validate(self.args)


def _args_message(exc: ValidationError) -> str:
    parts = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in ("args", *err["loc"]))
        parts.append(f"{loc}: {err['msg']}")
    return "; ".join(parts)


class HistoryEntry(WireModel):
    status: Text
    at: Timestamp
    detail: Text | None = None


class CommandObject(WireModel):
    command_id: Text
    instance_id: Text
    vehicle_id: Text | None = None
    type: CommandType
    args: ServedObject = Field(default_factory=dict)
    max_drift_m: float | None = None
    status: CommandStatus
    issued_by: Text
    issued_at: Timestamp
    expires_at: Timestamp
    progress: float | None = None
    history: list[HistoryEntry] = Field(default_factory=list)
