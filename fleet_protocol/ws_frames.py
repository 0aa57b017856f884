"""Text frames read into ops (:mod:`fleet_protocol.ws`), parsed once by a discriminated union.

Parse a text frame with :func:`parse_vehicle_op` or :func:`parse_client_op`; a bad
frame raises :class:`FrameError`, whose :meth:`FrameError.reply` is the push to send
back (an ``ack`` with ``ok: false`` when the frame carried a usable ``id``, else an
``error``). A ``batch`` only some of whose ops are valid is :class:`PartialBatch`.
"""

from __future__ import annotations

import json
from typing import Any, Literal, get_args

from pydantic import Field, TypeAdapter, ValidationError

from fleet_protocol.errors import (
    NOT_READ,
    ErrorBody,
    FieldError,
    error_text,
    long_integers,
    read_leniently,
    unreadable_json,
)
from fleet_protocol.text import shown_text
from fleet_protocol.ws import (
    MAX_BATCH_OPS,
    MAX_OP_ID_CHARS,
    AckPush,
    BatchOp,
    ClientOp,
    ErrorPush,
    VehicleOp,
    _Op,
    _SingleVehicleOp,
)

__all__ = [
    "FrameError",
    "PartialBatch",
    "error_body",
    "field_errors",
    "parse_client_op",
    "parse_vehicle_op",
]

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
    invalid op (its :meth:`~FrameError.reply` acks it by its own ``id``); and
    :attr:`in_order` the batch as sent, each op either parsed or its
    :class:`FrameError`, so that each is answered in its place. One bad op in a
    gateway's batch does not hold the others up (its units' samples among them).
    As a :class:`FrameError` it is the whole frame's refusal (every field named as in
    the batch: ``ops.1.samples.0.ts``), the answer when no op is valid.
    """

    def __init__(self, whole: FrameError, batch: BatchOp, in_order: list[Any]) -> None:
        super().__init__(whole.error, whole.op_id)
        self.batch = batch
        self.in_order = in_order
        self.refused = [op for op in in_order if isinstance(op, FrameError)]


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
    in_order: list[Any] = []  # each op parsed, or its refusal
    for inner in envelope.ops:
        try:
            in_order.append(_parse(_single_vehicle_adapter, json.dumps(inner)))
        except FrameError as exc:
            in_order.append(exc)
    valid = [op for op in in_order if not isinstance(op, FrameError)]
    if len(valid) == len(in_order):
        return None  # every op valid alone: the fault is not in one of them
    return PartialBatch(whole, BatchOp.model_construct(id=envelope.id, ops=valid), in_order)


def parse_client_op(frame: str | bytes) -> Any:
    """One op of ``/ws/client`` (a :data:`ClientOp` member), or :class:`FrameError`."""
    return _parse(_client_adapter, frame)


def _parse(adapter: TypeAdapter[Any], frame: str | bytes) -> Any:
    # A UTF-8 byte order mark before the JSON is read past, as an HTTP body's is.
    if isinstance(frame, str) and frame.startswith("\ufeff"):
        frame = frame[1:]
    elif isinstance(frame, bytes) and frame.startswith(b"\xef\xbb\xbf"):
        frame = frame[3:]
    try:
        # The core validator itself: TypeAdapter.validate_json only adds Python-side checks.
        return adapter.validator.validate_json(frame)
    except ValidationError as exc:
        error = exc
    if error.errors(include_url=False)[0]["type"] != "json_invalid":
        raise FrameError(error_body(error), _salvage_id(frame))
    value = read_leniently(frame)
    if value is NOT_READ:  # not JSON at all, or nested past what a reader goes to
        raise FrameError(error_body(error), _top_level_id(frame))
    if long := long_integers(value):  # past what Python's json reads: named all the same
        summary = "; ".join(f"{d.field}: {d.message}" for d in long[:3])
        body = ErrorBody(code="invalid", message=f"invalid op ({summary})", details=long)
        raise FrameError(body, _id_of(value))
    raise FrameError(error_body(_python_errors(adapter, value) or error), _id_of(value))


def _python_errors(adapter: TypeAdapter[Any], value: Any) -> ValidationError | None:
    """The errors with their fields for a frame the JSON parser refused but Python's
    ``json`` reads (a lone surrogate in a string: ``"\\ud800"``), as HTTP sees them."""
    try:
        adapter.validator.validate_python(value)
    except ValidationError as exc:
        return exc
    return None


def error_body(exc: ValidationError) -> ErrorBody:
    for err in exc.errors(include_url=False):  # the input read, never shown
        if err["type"] == "json_invalid":
            why = unreadable_json(err.get("ctx", {}).get("error", ""))
            message = f"the frame is {why}"  # the field named as HTTP names ``body``
            details = [FieldError(field="frame", message=message)]
            return ErrorBody(code="invalid", message=message, details=details)
    details = field_errors(exc)
    summary = "; ".join(f"{d.field}: {d.message}" for d in details[:3])
    return ErrorBody(code="invalid", message=f"invalid op ({summary})", details=details)


def field_errors(exc: ValidationError) -> list[FieldError]:
    """Each error's field (``samples.0.data.x``; pydantic's union tags left out) and message,
    never the value itself: what a 422 or a log line may show."""
    details: list[FieldError] = []
    for err in exc.errors(include_url=False):  # the input read, never shown
        loc = [str(part) for part in err["loc"]]
        # Drop the union tag pydantic inserts ("update_param" in ops.0.update_param.x).
        field = shown_text(".".join(p for p in loc if p not in _OP_TAGS))
        message = shown_text(error_text(err))
        if err["type"] == "union_tag_invalid" and err["ctx"]["tag"] == "auth":
            field, message = _join(field, "op"), _AUTH_AGAIN
        elif err["type"] == "union_tag_invalid":
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


#: An ``auth`` op past the socket's first frame, or on a socket whose header carried the
#: token: a documented op, not an unknown one.
_AUTH_AGAIN = (
    "'auth' is a socket's first frame only, when no header carried a token: "
    "this socket needs no other"
)

_OP_TAGS = frozenset(  # every op's tag: the members of the union, and batch
    m.model_fields["op"].default for m in (*get_args(get_args(_SingleVehicleOp)[0]), BatchOp)
)


def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


def _salvage_id(frame: str | bytes) -> str | None:
    """The frame's ``id``, when it has a usable one, so a failure can be acked."""
    value = read_leniently(frame)
    return None if value is NOT_READ else _id_of(value)


def _top_level_id(frame: str | bytes) -> str | None:
    """The ``id`` of a frame no reader takes whole (nested too deep), found by walking its
    text: a string key ``"id"`` of the outermost object, its value read alone. None when
    there is none, or the text is no JSON object."""
    text = frame.decode("utf-8", "replace") if isinstance(frame, bytes) else frame
    decoder = json.JSONDecoder()
    depth, i, n = 0, 0, len(text)
    while i < n:
        c = text[i]
        if c == '"':
            try:
                key, end = decoder.raw_decode(text, i)
            except ValueError:
                return None
            if depth == 1 and key == "id":
                colon = end
                while colon < n and text[colon] in " \t\r\n":
                    colon += 1
                if colon < n and text[colon] == ":":
                    start = colon + 1
                    while start < n and text[start] in " \t\r\n":
                        start += 1
                    if start < n and text[start] == '"':
                        try:
                            value, _ = decoder.raw_decode(text, start)
                        except ValueError:
                            return None
                        return _id_of({"id": value})
            i = end
            continue
        if c in "{[":
            depth += 1
        elif c in "}]":
            depth -= 1
        i += 1
    return None


def _id_of(value: Any) -> str | None:
    """The ``id`` of a frame read (:func:`read_leniently`), when it is a usable one."""
    op_id = value.get("id") if isinstance(value, dict) else None
    if isinstance(op_id, str) and 0 < len(op_id) <= MAX_OP_ID_CHARS and shown_text(op_id) == op_id:
        return op_id
    return None
