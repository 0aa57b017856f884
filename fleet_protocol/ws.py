"""WebSocket ops and pushes (API.md, "WebSocket"), parsed once by a discriminated union.

One envelope both ways: ``{"op": ..., "id"?: ..., <fields>}``. An op that
mirrors an ``/upper/*`` call is that call's body model plus ``op`` and ``id``
(``UpdateParamOp`` is ``UpdateParam`` with ``op="update_param"``), so the
fields are defined once. Ops in:

- ``/ws/vehicle`` (:data:`VehicleOp`): start_instance, finish_instance,
  update_param, update_fbmessage, heartbeat, register, unregister, subscribe,
  unsubscribe, publish, whoami, batch;
- ``/ws/client`` (:data:`ClientOp`): register, unregister, subscribe,
  unsubscribe, publish.

Pushes out: ``ack``, ``error``, ``command``, ``control``, ``event``,
``routes``, ``lagging``. A text frame is read into these by
:mod:`fleet_protocol.ws_frames`.

Binary frames (media topics) are in :mod:`fleet_protocol.media`.
"""

from __future__ import annotations

import functools
from typing import Annotated, Any, ClassVar, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SerializationInfo,
    SerializerFunctionWrapHandler,
    StrictInt,
    field_validator,
    model_serializer,
)
from pydantic_core import PydanticSerializationError, to_json

from fleet_protocol.commands import CommandObject
from fleet_protocol.common import Identifier, Timestamp, WireModel
from fleet_protocol.errors import ErrorBody
from fleet_protocol.served import safe_dumps
from fleet_protocol.text import Text
from fleet_protocol.topics import Topic
from fleet_protocol.upper import (
    ControlInfo,
    FailsafePolicy,
    FinishInstance,
    Heartbeat,
    StartInstance,
    UpdateFbMessage,
    UpdateParam,
)
from fleet_protocol.values import JsonValue

__all__ = [
    "MAX_BATCH_OPS",
    "MAX_OP_ID_CHARS",
    "MAX_TOPICS_PER_OP",
    "AbortPush",
    "AckPush",
    "AuthOp",
    "BatchOp",
    "ClientOp",
    "CommandPush",
    "ControlPush",
    "ErrorPush",
    "EventPush",
    "FailsafePush",
    "FinishInstanceOp",
    "HeartbeatOp",
    "LaggingPush",
    "PublishOp",
    "Push",
    "RegisterOp",
    "RoutesPush",
    "StartInstanceOp",
    "SubscribeOp",
    "UnregisterOp",
    "UnsubscribeOp",
    "UpdateFbMessageOp",
    "UpdateParamOp",
    "VehicleOp",
    "WhoAmIOp",
]

MAX_OP_ID_CHARS = 64
MAX_TOPICS_PER_OP = 64
MAX_BATCH_OPS = 256
#: Bound on a media frame's JSON header line.
MAX_MEDIA_HEADER_BYTES = 1024

OpId = Annotated[Text, Field(min_length=1, max_length=MAX_OP_ID_CHARS)]
TopicList = Annotated[list[Topic], Field(min_length=1, max_length=MAX_TOPICS_PER_OP)]


class _Op(WireModel):
    """Fields every op carries: ``id`` (optional; with it, the op is acked)."""

    id: OpId | None = None

    @field_validator("id", mode="before")
    @classmethod
    def _id_is_a_string(cls, value: object) -> object:
        """An ``id`` sent is a string: ``null`` is refused (left out, the op is not acked)."""
        if value is None:
            raise ValueError("an op id is a string of 1 to 64 characters; leave it out for no ack")
        return value


# -- ops mirroring /upper/* ---------------------------------------------------


class StartInstanceOp(_Op, StartInstance):
    op: Literal["start_instance"] = "start_instance"


class FinishInstanceOp(_Op, FinishInstance):
    op: Literal["finish_instance"] = "finish_instance"


class UpdateParamOp(_Op, UpdateParam):
    """Fields it does not know are kept aside (``model_extra``), never used: an op that
    carries nothing but them is refused, as ``POST /upper/update_param`` is."""

    model_config = ConfigDict(extra="allow")
    op: Literal["update_param"] = "update_param"


class UpdateFbMessageOp(_Op, UpdateFbMessage):
    op: Literal["update_fbmessage"] = "update_fbmessage"


class HeartbeatOp(_Op, Heartbeat):
    op: Literal["heartbeat"] = "heartbeat"


# -- topic ops ----------------------------------------------------------------


class _UnitOp(_Op):
    #: A gateway names the vehicle the op acts for; absent, the op is the
    #: connected unit's own (the vehicle, the gateway, the user).
    vehicle_id: Identifier | None = None


class RegisterOp(_UnitOp):
    """The topics this unit produces (added to what it registered before)."""

    op: Literal["register"] = "register"
    topics: TopicList


class UnregisterOp(_UnitOp):
    """Topics this unit no longer produces (**extension**: a gateway says so for a local
    unit that left)."""

    op: Literal["unregister"] = "unregister"
    topics: TopicList


class SubscribeOp(_UnitOp):
    op: Literal["subscribe"] = "subscribe"
    topics: TopicList
    #: At most one event per topic every ``throttle_ms`` (the latest value wins).
    throttle_ms: StrictInt = Field(default=0, ge=0, le=3_600_000)

    @field_validator("throttle_ms", mode="before")
    @classmethod
    def _null_is_no_throttle(cls, value: Any) -> Any:
        """``throttle_ms: null`` is the optional field not given (no throttle)."""
        return 0 if value is None else value


class UnsubscribeOp(_UnitOp):
    op: Literal["unsubscribe"] = "unsubscribe"
    topics: TopicList


class PublishOp(_UnitOp):
    op: Literal["publish"] = "publish"
    topic: Topic
    #: Any JSON value the store and JSON can hold (``fleet_protocol.values``); required
    #: (``null`` is a value: say it).
    data: JsonValue


class WhoAmIOp(_Op):
    """Whom this socket's token acts for (**extension**; ``GET /upper/whoami``)."""

    op: Literal["whoami"] = "whoami"


class AuthOp(_Op):
    """The first frame of a socket opened with no token in a header or in the URL (a
    browser cannot set headers, and a URL ends up in logs and histories): the token,
    then the socket is used as any other. Nothing else is read before it."""

    op: Literal["auth"] = "auth"
    token: Text = Field(min_length=1, max_length=512)


_SingleVehicleOp = Annotated[
    StartInstanceOp
    | FinishInstanceOp
    | UpdateParamOp
    | UpdateFbMessageOp
    | HeartbeatOp
    | RegisterOp
    | UnregisterOp
    | SubscribeOp
    | UnsubscribeOp
    | PublishOp
    | WhoAmIOp,
    Field(discriminator="op"),
]


class BatchOp(_Op):
    """Several ops in one frame (gateways); each inner op with an ``id`` is acked."""

    op: Literal["batch"] = "batch"
    ops: list[_SingleVehicleOp] = Field(min_length=1, max_length=MAX_BATCH_OPS)


VehicleOp = Annotated[_SingleVehicleOp | BatchOp, Field(discriminator="op")]
ClientOp = Annotated[
    RegisterOp | UnregisterOp | SubscribeOp | UnsubscribeOp | PublishOp,
    Field(discriminator="op"),
]

# -- pushes -------------------------------------------------------------------


class _Push(BaseModel):
    """A frame from the server. Optional fields left ``None`` are not written."""

    model_config = ConfigDict(extra="ignore", populate_by_name=True)
    _omit_if_none: ClassVar[frozenset[str]] = frozenset()

    @model_serializer(mode="wrap")
    def _omit_none(
        self, handler: SerializerFunctionWrapHandler, info: SerializationInfo
    ) -> dict[str, Any]:
        data: dict[str, Any] = handler(self)
        for name in self._omit_if_none:
            if data.get(name, 0) is None:
                del data[name]
        return data

    def frame(self) -> str:
        """The JSON text frame; a value JSON cannot hold (data stored by an older version)
        is sent escaped (``fleet_protocol.served.json_safe``), never refused."""
        try:
            return self.model_dump_json()
        except PydanticSerializationError:
            return safe_dumps(self.model_dump(mode="python"))


_ACK_OWN_FIELDS = frozenset({"op", "id", "ok", "error"})


@functools.cache
def _ack_clash(model: type[BaseModel]) -> set[str]:
    """A result model's fields that an ack's own fields take precedence over."""
    return set(_ACK_OWN_FIELDS & model.model_fields.keys())


class AckPush(_Push):
    """The answer to an op with an ``id``; on success, the HTTP answer's fields beside."""

    model_config = ConfigDict(extra="allow")
    _omit_if_none = frozenset({"error"})

    op: Literal["ack"] = "ack"
    id: Text
    ok: bool
    error: ErrorBody | None = None

    @classmethod
    def success(cls, op_id: str, result: BaseModel | dict[str, Any] | None = None) -> AckPush:
        fields = result.model_dump(mode="json") if isinstance(result, BaseModel) else result
        fields = {k: v for k, v in (fields or {}).items() if k not in ("op", "id", "ok", "error")}
        return cls(id=op_id, ok=True, **fields)

    @staticmethod
    def success_frame(op_id: str, result: BaseModel | dict[str, Any] | None = None) -> str:
        """``success(...).frame()`` without building the model (the hot path of every op)."""
        head = '{"op":"ack","id":' + to_json(op_id).decode() + ',"ok":true'
        if isinstance(result, BaseModel):
            clash = _ack_clash(type(result))
            body = result.model_dump_json(exclude=clash or None)  # in Rust
        elif result:
            if not _ACK_OWN_FIELDS.isdisjoint(result):
                result = {k: v for k, v in result.items() if k not in _ACK_OWN_FIELDS}
            body = to_json(result).decode()
        else:
            body = "{}"
        return head + "}" if body == "{}" else head + "," + body[1:]

    @classmethod
    def failure(cls, op_id: str, error: ErrorBody) -> AckPush:
        return cls(id=op_id, ok=False, error=error)


class ErrorPush(_Push):
    """A failed op that carried no ``id``."""

    op: Literal["error"] = "error"
    error: ErrorBody


class CommandPush(_Push, CommandObject):
    """A command object, pushed to the vehicle the moment it is accepted."""

    op: Literal["command"] = "command"

    @property
    def critical(self) -> bool:
        """A ``stop`` is never dropped by a queue bound."""
        return self.type == "stop"


class AbortPush(_Push):
    """Commands handed to the vehicle that ended on the server (cancelled, expired):
    it stops carrying them out at once."""

    op: Literal["abort"] = "abort"
    instance_id: Text
    command_ids: list[Text] = Field(min_length=1)

    @property
    def critical(self) -> bool:
        """Like a ``stop``, never dropped by a queue bound."""
        return True


class ControlPush(_Push):
    """Who holds remote control of the instance now (``null``: nobody)."""

    op: Literal["control"] = "control"
    instance_id: Text
    control: ControlInfo | None = None


class FailsafePush(_Push):
    """The vehicle's failsafe policy changed: apply it, and acknowledge its version."""

    op: Literal["failsafe"] = "failsafe"
    instance_id: Text
    failsafe: FailsafePolicy


class EventPush(_Push):
    """A message on a topic. A gateway passes the events from above down to its units as
    they came, rebuilt from this model: ``source`` is one of its fields, and a field it
    does not know (a newer server's) is kept too, not dropped on the way."""

    model_config = ConfigDict(extra="allow")
    _omit_if_none = frozenset({"snapshot", "ts", "source"})

    op: Literal["event"] = "event"
    topic: Text
    data: Any = None
    #: ``true`` on the current state sent first after a subscribe.
    snapshot: bool | None = None
    #: The server's time of the change (none on an event between a gateway's units).
    ts: Timestamp | None = None
    #: The unit that published it (``vehicle:<id>``, ``gateway:<id>``, ``user:<name>``);
    #: none on a topic the server writes, and on an event between a gateway's units.
    source: Text | None = None


class RoutesPush(_Push):
    """The part of the routing table this unit takes part in.

    ``produces``: each topic it registered, with the units consuming it;
    ``consumes``: each topic it subscribed to, with the units producing it;
    for a gateway, ``forward_up`` (what it sends to the cloud) and
    ``forward_down`` (what it delivers to its units from above).
    """

    op: Literal["routes"] = "routes"
    unit: Text
    produces: dict[Text, list[Text]] = Field(default_factory=dict)
    consumes: dict[Text, list[Text]] = Field(default_factory=dict)
    forward_up: list[Text] = Field(default_factory=list)
    forward_down: list[Text] = Field(default_factory=list)


class LaggingPush(_Push):
    """Messages were dropped for this connection since the last ``lagging``."""

    _omit_if_none = frozenset({"total"})

    op: Literal["lagging"] = "lagging"
    dropped: int = Field(ge=1)
    #: Dropped since the connection opened.
    total: int | None = None


Push = (
    AckPush
    | ErrorPush
    | CommandPush
    | AbortPush
    | ControlPush
    | FailsafePush
    | EventPush
    | RoutesPush
    | LaggingPush
)
