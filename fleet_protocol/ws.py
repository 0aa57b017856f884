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

Pushes out (:mod:`fleet_protocol.ws_pushes`, named here too): ``ack``,
``error``, ``command``, ``control``, ``event``, ``routes``, ``lagging``. A text
frame is read into these by :mod:`fleet_protocol.ws_frames`.

Binary frames (media topics) are in :mod:`fleet_protocol.media`.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import (
    ConfigDict,
    Field,
    StrictInt,
    field_validator,
)

from fleet_protocol.common import Identifier, WireModel
from fleet_protocol.text import Text
from fleet_protocol.topics import Topic
from fleet_protocol.upper import (
    FinishInstance,
    Heartbeat,
    StartInstance,
    UpdateFbMessage,
    UpdateParam,
)
from fleet_protocol.values import JsonValue
from fleet_protocol.ws_pushes import (
    AbortPush,
    AckPush,
    CommandPush,
    ControlPush,
    ErrorPush,
    EventPush,
    FailsafePush,
    LaggingPush,
    Push,
    RoutesPush,
)

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
