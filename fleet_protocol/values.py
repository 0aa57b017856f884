"""What JSON and the store can hold: the limits every wire model keeps, and free-form values.

The server stores what it accepts in MongoDB (BSON; FerretDB in the tests)
and sends it on as JSON, so a wire model refuses, with the path of the bad
value in the 422, what either cannot hold (``docs/limits.md``):

- integers within signed 64-bit, :data:`MIN_INT` to :data:`MAX_INT` (BSON's
  widest integer);
- finite floats: no NaN, no ±Infinity (not JSON numbers; FerretDB closes the
  connection on a NaN);
- strings without lone UTF-16 surrogates (U+D800..U+DFFF): neither UTF-8 nor
  BSON can hold one, yet Python's ``json`` decodes ``"\\ud800"`` into one;
- free-form objects and arrays nested at most :data:`MAX_JSON_DEPTH` deep;
- keys of free-form objects: strings of at most :data:`MAX_KEY_CHARS`
  characters, not starting with ``$`` (a MongoDB operator), without ``.`` (a
  MongoDB path) and without NUL (BSON keys are C strings).

:data:`JsonValue`, :data:`JsonObject` and their bounded variants check a
free-form value in one walk that stops at the first bad value and names it:
``data.reading.0`` under the field, so ``samples.3.data.reading.0`` in the
422. A ``str`` field is :data:`fleet_protocol.text.Text`, without lone
surrogates (:mod:`fleet_protocol.text`, which also holds ``Label``). The
timestamp range is :data:`MIN_TIMESTAMP` to :data:`MAX_TIMESTAMP`, the latter
excluded for a point in time (:data:`fleet_protocol.common.Timestamp`) and
included for a window's bound (:data:`fleet_protocol.common.TimeBound`).

The other direction, a value stored before a rule existed made safe to send,
is :mod:`fleet_protocol.served`; the words of a refusal (a 422's message, a
body that cannot be read) are in :mod:`fleet_protocol.errors`.

Pydantic only: the server, the agent and the operator tools all check with it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from datetime import UTC, datetime
from typing import Annotated, Any

from pydantic import PlainValidator, ValidationError, WithJsonSchema
from pydantic_core import InitErrorDetails, PydanticCustomError, to_json

from fleet_protocol.text import SURROGATE, SURROGATE_MSG, has_surrogate, shown_text

__all__ = [
    "MAX_INT",
    "MAX_JSON_DEPTH",
    "MAX_KEY_CHARS",
    "MAX_PARAMS",
    "MAX_PARAMS_BYTES",
    "MAX_SAMPLE_DATA_BYTES",
    "MAX_TIMESTAMP",
    "MIN_INT",
    "MIN_TIMESTAMP",
    "JsonObject",
    "JsonValue",
    "Params",
    "SampleData",
    "json_problem",
]

#: Integers: signed 64-bit, what BSON's widest integer (``int64``) holds.
MIN_INT = -(2**63)
MAX_INT = 2**63 - 1
#: Nesting of a free-form value (the value itself is level 1). MongoDB refuses
#: documents nested past 100 levels and a sample's ``data`` already sits four
#: deep in its telemetry bucket (bucket, samples array, sample, data); 32 is
#: far past any sensor reading or parameter set, and bounds every recursive
#: walk (this check, the encoders, the drivers) well inside Python's stack.
MAX_JSON_DEPTH = 32
#: A free-form object's keys: at most this many characters.
MAX_KEY_CHARS = 128
#: Entries in a ``params`` object (``start_instance``, ``update_param``), and in the
#: parameters a vehicle's instance holds once merged.
MAX_PARAMS = 512
#: Bytes of compact UTF-8 JSON of a ``params`` object, and of the merged parameters.
MAX_PARAMS_BYTES = 65536
#: A sample's ``data``: at most this many bytes of compact UTF-8 JSON.
MAX_SAMPLE_DATA_BYTES = 8192
#: A sample's ``depth_m`` (metres, positive down): 1 km above the surface is past any
#: mast or aerial, 12 km below it past the deepest trench (10.9 km).
MIN_DEPTH_M = -1_000.0
MAX_DEPTH_M = 12_000.0
#: Timestamps: a point in time (every ``Timestamp`` field: a sample's ``ts``...) lies
#: from ``MIN_TIMESTAMP`` included to ``MAX_TIMESTAMP`` excluded; a window's bound (the
#: ``from``/``to`` query parameters, ``TimeBound``) from one to the other, both included,
#: so the widest window, whose ``to`` is excluded, holds every point. A vehicle without
#: a GPS fix may send the epoch (1970); 2100 is far past any real clock.
MIN_TIMESTAMP = datetime(1970, 1, 1, tzinfo=UTC)
MAX_TIMESTAMP = datetime(2100, 1, 1, tzinfo=UTC)

_INT_MSG = f"an integer must lie within signed 64-bit ({MIN_INT} to {MAX_INT})"
_FLOAT_MSG = "NaN and Infinity are not JSON numbers: send a finite number or null"
_DEPTH_MSG = f"nested deeper than {MAX_JSON_DEPTH} levels"

Path = list[str | int]
#: A bad value: its path (innermost first, reversed once at the end) and what is wrong.
Problem = tuple[Path, str]


def _key_problem(key: object) -> str | None:
    if type(key) is not str:
        if not isinstance(key, str):
            return "an object's keys are strings"
        key = str(key)
    if len(key) > MAX_KEY_CHARS:
        return f"a key has at most {MAX_KEY_CHARS} characters"
    if key[:1] == "$":
        return "a key may not start with '$'"
    if "." in key:
        return "a key may not hold '.'"
    if "\x00" in key:
        return "a key may not hold NUL"
    if has_surrogate(key):
        return SURROGATE_MSG
    return None


def _shown_key(key: object) -> str:
    """A key as the 422's path shows it: text JSON can hold, and not too long."""
    text = key if isinstance(key, str) else repr(key)
    if len(text) > MAX_KEY_CHARS:
        text = text[:MAX_KEY_CHARS] + "…"
    return shown_text(text)


def _scalar_problem(value: Any) -> str | None:
    """What is wrong with a value that is neither an object nor an array (None: nothing)."""
    if isinstance(value, str):
        return SURROGATE_MSG if has_surrogate(value) else None
    if isinstance(value, bool) or value is None:
        return None
    if isinstance(value, int):
        return None if MIN_INT <= value <= MAX_INT else _INT_MSG
    if isinstance(value, float):
        return None if math.isfinite(value) else _FLOAT_MSG
    return f"a {type(value).__name__} is not a JSON value"


def _object_problem(value: dict[Any, Any], depth: int) -> Problem | None:
    if depth > MAX_JSON_DEPTH:
        return [], _DEPTH_MSG
    for key, item in value.items():
        # The common case inline: an ASCII key, a plain scalar.
        if (
            type(key) is not str
            or not key.isascii()
            or not key
            or key[0] == "$"
            or ("." in key or "\x00" in key or len(key) > MAX_KEY_CHARS)
        ):
            message = _key_problem(key)
            if message is not None:
                return [_shown_key(key)], message
        kind = type(item)
        if kind is str:
            if item.isascii() or SURROGATE.search(item) is None:
                continue
            return [key], SURROGATE_MSG
        if kind is float:
            if item - item == 0.0:  # NaN - NaN and inf - inf are NaN
                continue
            return [key], _FLOAT_MSG
        if kind is int:
            if MIN_INT <= item <= MAX_INT:
                continue
            return [key], _INT_MSG
        if kind is bool or item is None:
            continue
        problem = _nested_problem(item, depth)
        if problem is not None:
            problem[0].append(key)
            return problem
    return None


def _array_problem(value: list[Any] | tuple[Any, ...], depth: int) -> Problem | None:
    if depth > MAX_JSON_DEPTH:
        return [], _DEPTH_MSG
    for index, item in enumerate(value):
        kind = type(item)
        if kind is float:
            if item - item == 0.0:
                continue
            return [index], _FLOAT_MSG
        if kind is int:
            if MIN_INT <= item <= MAX_INT:
                continue
            return [index], _INT_MSG
        if kind is str:
            if item.isascii() or SURROGATE.search(item) is None:
                continue
            return [index], SURROGATE_MSG
        if kind is bool or item is None:
            continue
        problem = _nested_problem(item, depth)
        if problem is not None:
            problem[0].append(index)
            return problem
    return None


def _nested_problem(value: Any, depth: int) -> Problem | None:
    """``value`` sits at ``depth``: an object or array in it is one level deeper."""
    if isinstance(value, dict):
        return _object_problem(value, depth + 1)
    if isinstance(value, list | tuple):
        return _array_problem(value, depth + 1)
    message = _scalar_problem(value)
    return None if message is None else ([], message)


def json_problem(value: Any) -> tuple[tuple[str | int, ...], str] | None:
    """The first value in ``value`` that JSON or the store cannot hold: its path and what is
    wrong with it; ``None`` when every value is fine."""
    problem = _nested_problem(value, 0)
    if problem is None:
        return None
    path, message = problem
    return tuple(reversed(path)), message


def _refuse(path: tuple[str | int, ...], message: str, value: Any) -> ValidationError:
    error = PydanticCustomError("json_value", "{reason}", {"reason": message})
    return ValidationError.from_exception_data(
        "JSON value", [InitErrorDetails(type=error, loc=path, input=value)]
    )


def _checker(
    *,
    kind: type | None = None,
    optional: bool = False,
    max_keys: int | None = None,
    max_bytes: int | None = None,
) -> Callable[[Any], Any]:
    """A plain validator: the value as it came (an object is copied, not deep-copied) or a
    ``ValidationError`` whose path leads from the field to the first bad value."""

    def check(value: Any) -> Any:
        if value is None and optional:
            return None
        if kind is dict:
            if not isinstance(value, dict):
                raise _refuse((), "an object is expected here", value)
            if max_keys is not None and len(value) > max_keys:
                raise _refuse((), f"at most {max_keys} entries are accepted", value)
            problem = _object_problem(value, 1)
            if problem is not None:
                path, message = problem
                raise _refuse(tuple(reversed(path)), message, value)
            if max_bytes is not None and len(value) and len(to_json(value)) > max_bytes:
                size = len(to_json(value))
                raise _refuse((), f"{size} bytes of JSON; at most {max_bytes} are accepted", value)
            return dict(value)
        found = json_problem(value)
        if found is not None:
            raise _refuse(*found, value)
        return value

    return check


_ANY_SCHEMA = WithJsonSchema({"description": "any JSON value (docs/limits.md)"})
_OBJECT_SCHEMA = WithJsonSchema(
    {"type": "object", "description": "a free-form JSON object (docs/limits.md)"}
)

#: Any JSON value that JSON and the store can hold (``publish`` data).
JsonValue = Annotated[Any, PlainValidator(_checker()), _ANY_SCHEMA]
#: A free-form JSON object that JSON and the store can hold.
JsonObject = Annotated[dict[str, Any], PlainValidator(_checker(kind=dict)), _OBJECT_SCHEMA]
#: ``params`` of ``start_instance`` / ``update_param``: at most :data:`MAX_PARAMS` entries
#: and :data:`MAX_PARAMS_BYTES` of JSON.
Params = Annotated[
    dict[str, Any],
    PlainValidator(_checker(kind=dict, max_keys=MAX_PARAMS, max_bytes=MAX_PARAMS_BYTES)),
    WithJsonSchema(
        {
            "type": "object",
            "maxProperties": MAX_PARAMS,
            "description": f"free-form parameters, at most {MAX_PARAMS_BYTES} bytes of JSON",
        }
    ),
]
#: A sample's ``data``: an object of at most :data:`MAX_SAMPLE_DATA_BYTES`, or null.
SampleData = Annotated[
    dict[str, Any] | None,
    PlainValidator(_checker(kind=dict, optional=True, max_bytes=MAX_SAMPLE_DATA_BYTES)),
    WithJsonSchema(
        {
            "anyOf": [{"type": "object"}, {"type": "null"}],
            "description": f"free-form readings, at most {MAX_SAMPLE_DATA_BYTES} bytes of JSON",
        }
    ),
]
