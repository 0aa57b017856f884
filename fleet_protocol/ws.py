"""WebSocket ops and pushes (API.md, "WebSocket"), parsed once by a discriminated union.

One envelope both ways: ``{"op": ..., "id"?: ..., <fields>}``. An op that
mirrors an ``/upper/*`` call is that call's body model plus ``op`` and ``id``
(``UpdateParamOp`` is ``UpdateParam`` with ``op="update_param"``), so the
fields are defined once. Ops in:

- ``/ws/vehicle`` (:data:`VehicleOp`): start_instance, finish_instance,
  update_param, update_fbmessage, heartbeat, register, subscribe,
  unsubscribe, publish, batch;
- ``/ws/client`` (:data:`ClientOp`): register, subscribe, unsubscribe,
  publish.

Pushes out: ``ack``, ``error``, ``command``, ``control``, ``event``,
``routes``, ``lagging``. Parse a text frame with :func:`parse_vehicle_op` or
:func:`parse_client_op`; a bad frame raises :class:`FrameError`, whose
:meth:`FrameError.reply` is the push to send back (an ``ack`` with
``ok: false`` when the frame carried a usable ``id``, else an ``error``).

Binary frames (media topics) are in :mod:`fleet_protocol.media`.
"""

from __future__ import annotations

import functools
import json
from typing import Annotated, Any, ClassVar, Literal, get_args

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SerializationInfo,
    SerializerFunctionWrapHandler,
    TypeAdapter,
    ValidationError,
    model_serializer,
)
from pydantic_core import PydanticSerializationError, to_json

from fleet_protocol.commands import CommandObject
from fleet_protocol.common import Identifier, Timestamp, WireModel
from fleet_protocol.errors import ErrorBody, FieldError
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
from fleet_protocol.values import JsonValue, Text, safe_dumps, shown_text

__all__ = [
    "MAX_BATCH_OPS",
    "MAX_OP_ID_CHARS",
    "MAX_TOPICS_PER_OP",
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
    "FrameError",
    "HeartbeatOp",
    "LaggingPush",
    "PartialBatch",
    "PublishOp",
    "Push",
    "RegisterOp",
    "RoutesPush",
    "StartInstanceOp",
    "SubscribeOp",
    "UnsubscribeOp",
    "UpdateFbMessageOp",
    "UpdateParamOp",
    "VehicleOp",
    "field_errors",
    "parse_client_op",
    "parse_vehicle_op",
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


# -- ops mirroring /upper/* ---------------------------------------------------


class StartInstanceOp(_Op, StartInstance):
    op: Literal["start_instance"] = "start_instance"


class FinishInstanceOp(_Op, FinishInstance):
    op: Literal["finish_instance"] = "finish_instance"


class UpdateParamOp(_Op, UpdateParam):
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


class SubscribeOp(_UnitOp):
    op: Literal["subscribe"] = "subscribe"
    topics: TopicList
    #: At most one event per topic every ``throttle_ms`` (the latest value wins).
    throttle_ms: int = Field(default=0, ge=0, le=3_600_000)


class UnsubscribeOp(_UnitOp):
    op: Literal["unsubscribe"] = "unsubscribe"
    topics: TopicList


class PublishOp(_UnitOp):
    op: Literal["publish"] = "publish"
    topic: Topic
    #: Any JSON value the store and JSON can hold (``fleet_protocol.values``).
    data: JsonValue = None


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
    | SubscribeOp
    | UnsubscribeOp
    | PublishOp,
    Field(discriminator="op"),
]


class BatchOp(_Op):
    """Several ops in one frame (gateways); each inner op with an ``id`` is acked."""

    op: Literal["batch"] = "batch"
    ops: list[_SingleVehicleOp] = Field(min_length=1, max_length=MAX_BATCH_OPS)


VehicleOp = Annotated[_SingleVehicleOp | BatchOp, Field(discriminator="op")]
ClientOp = Annotated[
    RegisterOp | SubscribeOp | UnsubscribeOp | PublishOp, Field(discriminator="op")
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
        is sent escaped (``fleet_protocol.values.json_safe``), never refused."""
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
    _omit_if_none = frozenset({"snapshot", "ts"})

    op: Literal["event"] = "event"
    topic: Text
    data: Any = None
    #: ``true`` on the current state sent first after a subscribe.
    snapshot: bool | None = None
    ts: Timestamp | None = None


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
    | ControlPush
    | FailsafePush
    | EventPush
    | RoutesPush
    | LaggingPush
)

# -- parsing ------------------------------------------------------------------

_vehicle_adapter: TypeAdapter[Any] = TypeAdapter(VehicleOp)
_client_adapter: TypeAdapter[Any] = TypeAdapter(ClientOp)


class FrameError(Exception):
    """A frame that is not a valid op; :meth:`reply` is what to send back."""

    def __init__(self, error: ErrorBody, op_id: str | None = None) -> None:
        super().__init__(error.message)
        self.error = error
        self.op_id = op_id

    def reply(self) -> AckPush | ErrorPush:
        if self.op_id is not None:
            return AckPush.failure(self.op_id, self.error)
        return ErrorPush(error=self.error)


class PartialBatch(FrameError):
    """A ``batch`` whose envelope is sound but some of whose ops are not valid.

    The batch is taken as its ops sent one after the other: :attr:`batch` holds the
    valid ones, in order, to be run; :attr:`refused` one :class:`FrameError` per
    invalid op (its :meth:`~FrameError.reply` acks it by its own ``id``). One bad op in
    a gateway's batch does not hold the others up (its units' samples among them).
    As a :class:`FrameError` it is the whole frame's refusal (every field named as in
    the batch: ``ops.1.samples.0.ts``), the answer when no op is valid.
    """

    def __init__(self, whole: FrameError, batch: BatchOp, refused: list[FrameError]) -> None:
        super().__init__(whole.error, whole.op_id)
        self.batch = batch
        self.refused = refused


class _BatchFrame(_Op):
    """A batch's envelope, its ops not read yet."""

    op: Literal["batch"]
    ops: list[Any] = Field(min_length=1, max_length=MAX_BATCH_OPS)


_single_vehicle_adapter: TypeAdapter[Any] = TypeAdapter(_SingleVehicleOp)


def parse_vehicle_op(frame: str | bytes) -> Any:
    """One op of ``/ws/vehicle`` (a :data:`VehicleOp` member), or :class:`FrameError`
    (:class:`PartialBatch` for a sound batch some of whose ops are not valid)."""
    try:
        return _parse(_vehicle_adapter, frame)
    except FrameError as whole:
        raise _partial_batch(frame, whole) or whole from None


def _partial_batch(frame: str | bytes, whole: FrameError) -> PartialBatch | None:
    """The batch's valid ops and the others' refusals, when ``frame`` is a batch whose
    envelope is sound; None for anything else (the frame is refused whole)."""
    try:
        envelope = _BatchFrame.model_validate(json.loads(frame))
    except (ValueError, RecursionError):  # not JSON, or not a batch (a ValidationError)
        return None
    valid: list[Any] = []
    refused: list[FrameError] = []
    for inner in envelope.ops:
        try:
            valid.append(_parse(_single_vehicle_adapter, json.dumps(inner)))
        except FrameError as exc:
            refused.append(exc)
    if not refused:
        return None  # every op valid alone: the fault is not in one of them
    return PartialBatch(whole, BatchOp.model_construct(id=envelope.id, ops=valid), refused)


def parse_client_op(frame: str | bytes) -> Any:
    """One op of ``/ws/client`` (a :data:`ClientOp` member), or :class:`FrameError`."""
    return _parse(_client_adapter, frame)


def _parse(adapter: TypeAdapter[Any], frame: str | bytes) -> Any:
    try:
        # The core validator itself: TypeAdapter.validate_json only adds Python-side checks.
        return adapter.validator.validate_json(frame)
    except ValidationError as exc:
        error = exc
    if error.errors(include_url=False)[0]["type"] == "json_invalid":
        error = _python_errors(adapter, frame) or error
    raise FrameError(_error_body(error), _salvage_id(frame))


def _python_errors(adapter: TypeAdapter[Any], frame: str | bytes) -> ValidationError | None:
    """The errors with their fields for a frame the JSON parser refused but Python's
    ``json`` reads (a lone surrogate in a string: ``"\\ud800"``), as HTTP sees them."""
    try:
        value = json.loads(frame)
    except (ValueError, RecursionError):
        return None
    try:
        adapter.validator.validate_python(value)
    except ValidationError as exc:
        return exc
    return None


def _error_body(exc: ValidationError) -> ErrorBody:
    if any(err["type"] == "json_invalid" for err in exc.errors(include_url=False)):
        return ErrorBody(code="invalid", message="the frame is not valid JSON")
    details = field_errors(exc)
    summary = "; ".join(f"{d.field}: {d.message}" for d in details[:3])
    return ErrorBody(code="invalid", message=f"invalid op ({summary})", details=details)


def field_errors(exc: ValidationError) -> list[FieldError]:
    """Each error's field (``samples.0.data.x``; pydantic's union tags left out) and message,
    never the value itself: what a 422 or a log line may show."""
    details: list[FieldError] = []
    for err in exc.errors(include_url=False, include_input=False):
        loc = [str(part) for part in err["loc"]]
        # Drop the union tag pydantic inserts ("update_param" in ops.0.update_param.x).
        field = shown_text(".".join(p for p in loc if p not in _OP_TAGS))
        message = shown_text(err["msg"].removeprefix("Value error, "))
        if err["type"] == "union_tag_invalid":
            field, message = (
                _join(field, "op"),
                f"unknown op; expected one of {err['ctx']['expected_tags']}",
            )
        elif err["type"] == "union_tag_not_found":
            field, message = _join(field, "op"), "the frame has no 'op'"
        elif not field:
            field = "frame"
        details.append(FieldError(field=field, message=message))
    return details


_OP_TAGS = frozenset(  # every op's tag: the members of the union, and batch
    m.model_fields["op"].default for m in (*get_args(get_args(_SingleVehicleOp)[0]), BatchOp)
)


def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


def _salvage_id(frame: str | bytes) -> str | None:
    """The frame's ``id``, when it has a usable one, so a failure can be acked."""
    try:
        value = json.loads(frame)
    except (ValueError, RecursionError):  # RecursionError: nested past the stack
        return None
    op_id = value.get("id") if isinstance(value, dict) else None
    if isinstance(op_id, str) and 0 < len(op_id) <= MAX_OP_ID_CHARS and shown_text(op_id) == op_id:
        return op_id
    return None
