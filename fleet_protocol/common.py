"""Shared field types: timestamps, identifiers, positions, samples."""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from datetime import UTC, datetime
from typing import Annotated, Any, NotRequired

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    GetPydanticSchema,
    PlainSerializer,
    StrictFloat,
    StrictInt,
    WithJsonSchema,
)
from pydantic_core import PydanticCustomError, core_schema
from typing_extensions import TypedDict

from fleet_protocol.served import json_safe
from fleet_protocol.values import (
    MAX_DEPTH_M,
    MAX_SAMPLE_DATA_BYTES,
    MAX_TIMESTAMP,
    MIN_DEPTH_M,
    MIN_TIMESTAMP,
    SampleData,
)

__all__ = [
    "ID_PATTERN",
    "ID_RULE",
    "MAX_SAMPLE_DATA_BYTES",
    "Identifier",
    "LatLon",
    "Latitude",
    "Longitude",
    "Sample",
    "SampleDoc",
    "TimeBound",
    "Timestamp",
    "WireModel",
    "format_ts",
    "now_ts",
    "parse_ts",
    "refuse_null",
    "utcnow",
]

#: Identifiers (vehicles, users, gateways) become topic segments
#: (``vehicle/<id>/telemetry``), so they follow the topic grammar.
ID_PATTERN = r"^[a-z0-9][a-z0-9_-]{0,63}$"
#: :data:`ID_PATTERN` in words, for a person told why an id or a name is refused.
ID_RULE = "1 to 64 characters of a-z, 0-9, - and _, the first a letter or a digit"


def refuse_null(cls: Any, value: Any) -> Any:
    """A field validator (``mode="before"``) of a patch's fields: ``null`` is refused, a
    422 naming the field. Left out, a field keeps its value; ``null`` kept it too, which a
    client meaning "none" took for a change made."""
    if value is None:
        raise PydanticCustomError(
            "null_keeps", "null is no value here: leave the field out to keep what it is"
        )
    return value


def utcnow() -> datetime:
    return datetime.now(UTC)


def _as_utc(value: datetime) -> datetime:
    if value.tzinfo is None:
        return value.replace(tzinfo=UTC)
    return value.astimezone(UTC)


def format_ts(value: datetime) -> str:
    """ISO 8601 UTC with milliseconds, the contract's one time format."""
    global _formatted
    tz = value.tzinfo
    if tz is not UTC and (tz is None or value.utcoffset()):  # UTC by another tzinfo: as it is
        value = _as_utc(value)
    # The text up to the second is kept while the second is the same (the hot paths
    # stamp thousands a second): the rest is a table look-up. The second is told by its
    # fields (a new datetime without its microseconds costs several times more).
    second = (value.second, value.minute, value.hour, value.day, value.month, value.year)
    kept, prefix = _formatted
    if second != kept:
        # "2026-05-01T12:00:00+00:00" less its offset: isoformat is the fastest spelling.
        prefix = value.replace(microsecond=0).isoformat()[:19]
        _formatted = (second, prefix)
    return prefix + _MILLIS[value.microsecond // 1000]


_formatted: tuple[tuple[int, ...] | None, str] = (None, "")


_second: tuple[int, str] = (-1, "")
_MILLIS = tuple(f".{milli:03d}Z" for milli in range(1000))


def now_ts() -> str:
    """``format_ts(utcnow())`` for the hot paths: the text up to the second is reused."""
    global _second
    sec, milli = divmod(time.time_ns() // 1_000_000, 1000)
    cached_sec, prefix = _second
    if sec != cached_sec:
        prefix = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(sec))
        _second = (sec, prefix)
    return prefix + _MILLIS[milli]


def parse_ts(text: str) -> datetime:
    return _as_utc(datetime.fromisoformat(text.replace("Z", "+00:00")))


_RANGE_CTX = {"low": format_ts(MIN_TIMESTAMP), "high": format_ts(MAX_TIMESTAMP)}


def _time_schema(upper: str, message: str) -> Any:
    """The schema of a datetime from ``MIN_TIMESTAMP`` on and under (``upper`` ``lt``) or
    up to (``le``) ``MAX_TIMESTAMP``, always aware in UTC.

    pydantic checks the bounds itself (a naive time counts as UTC). A time in UTC
    already (``Z``, ``+00:00``: what clients send) is taken as pydantic reads it, with
    no Python call; any other (naive, or another offset) is then converted to UTC.
    Every failure (not a time, out of range) is the one error ``timestamp``: ``message``.
    """

    def schema(_source: Any, _handler: Any) -> core_schema.CoreSchema:
        bounds: dict[str, Any] = {"ge": MIN_TIMESTAMP, upper: MAX_TIMESTAMP}
        in_utc = core_schema.datetime_schema(tz_constraint=0, **bounds)
        other = core_schema.no_info_after_validator_function(
            _as_utc, core_schema.datetime_schema(**bounds)
        )
        return core_schema.custom_error_schema(
            core_schema.union_schema([in_utc, other], mode="left_to_right"),
            custom_error_type="timestamp",
            custom_error_message=message,
        )

    return schema


_POINT_MSG = f"a timestamp is ISO 8601 from {_RANGE_CTX['low']} to before {_RANGE_CTX['high']}"
_BOUND_MSG = f"a time bound is ISO 8601 from {_RANGE_CTX['low']} to {_RANGE_CTX['high']}"

#: A point in time: ISO 8601 in, ``format_ts`` out; from 1970-01-01 (included) to
#: 2100-01-01 (excluded: ``fleet_protocol.values.MIN_TIMESTAMP`` / ``MAX_TIMESTAMP``).
#: Its value has an offset of zero (its tzinfo ``UTC`` or pydantic's own zero offset).
Timestamp = Annotated[
    datetime,
    GetPydanticSchema(_time_schema("lt", _POINT_MSG)),
    PlainSerializer(format_ts, return_type=str, when_used="json"),
    WithJsonSchema(
        {
            "type": "string",
            "format": "date-time",
            "description": (
                f"ISO 8601, UTC; from {_RANGE_CTX['low']} to before {_RANGE_CTX['high']}"
            ),
        }
    ),
]

#: A bound of a time window (``from``, ``to``): as :data:`Timestamp`, but 2100-01-01
#: itself included, so that a window (``to`` excluded) can hold every point in time.
TimeBound = Annotated[
    datetime,
    GetPydanticSchema(_time_schema("le", _BOUND_MSG)),
    PlainSerializer(format_ts, return_type=str, when_used="json"),
    WithJsonSchema(
        {
            "type": "string",
            "format": "date-time",
            "description": f"ISO 8601, UTC; from {_RANGE_CTX['low']} to {_RANGE_CTX['high']}",
        }
    ),
]
Identifier = Annotated[str, Field(pattern=ID_PATTERN, examples=["usv-1"])]
Latitude = Annotated[StrictFloat, Field(ge=-90, le=90, allow_inf_nan=False)]
Longitude = Annotated[StrictFloat, Field(ge=-180, le=180, allow_inf_nan=False)]


class WireModel(BaseModel):
    """Base of every message: unknown fields are ignored (clients may be newer).

    Every value is one JSON and the store can hold (``fleet_protocol.values``):
    floats are finite (``allow_inf_nan=False`` for every float field), strings
    are ``Text`` (no lone surrogates), free-form values are ``JsonValue`` /
    ``JsonObject``, timestamps are ``Timestamp`` (1970 to 2100).
    """

    model_config = ConfigDict(extra="ignore", populate_by_name=True, allow_inf_nan=False)


class LatLon(WireModel):
    lat: Latitude
    lon: Longitude


class Sample(WireModel):
    """One telemetry sample. ``seq`` rises strictly per vehicle.

    ``ts`` between 1970 and 2100; ``data`` a free-form object of at most
    ``MAX_SAMPLE_DATA_BYTES`` of JSON holding what JSON and the store can hold
    (64-bit integers, finite floats, no lone surrogates, keys without a leading
    ``$``, ``.`` or NUL, nesting at most ``MAX_JSON_DEPTH``: ``docs/limits.md``).
    """

    seq: StrictInt = Field(ge=1, le=2**62, description="per vehicle, rising; 0 means none yet")
    ts: Timestamp
    lat: Latitude
    lon: Longitude
    #: Metres, positive down: from above any mast to below the deepest trench.
    depth_m: StrictFloat | None = Field(
        default=None, ge=MIN_DEPTH_M, le=MAX_DEPTH_M, allow_inf_nan=False
    )
    heading_deg: StrictFloat | None = Field(default=None, ge=0, le=360, allow_inf_nan=False)
    speed_mps: StrictFloat | None = Field(default=None, ge=0, le=200, allow_inf_nan=False)
    battery_pct: StrictFloat | None = Field(default=None, ge=0, le=100, allow_inf_nan=False)
    data: SampleData = None

    @classmethod
    def from_stored(cls, doc: Mapping[str, Any]) -> Sample:
        """A sample as the server stored it, not checked again (it was, when it came in).
        One an older version stored that breaks a rule is served escaped: what JSON
        cannot hold in ``data`` replaced (``json_safe``), a non-finite number as null."""
        fields = {k: v for k, v in doc.items() if k in cls.model_fields}
        for name, value in fields.items():
            if isinstance(value, float) and not math.isfinite(value):
                fields[name] = None
        if fields.get("data") is not None:
            fields["data"] = json_safe(fields["data"])
        return cls.model_construct(**fields)


def _doc_form(model: type[BaseModel]) -> Any:
    """``model`` as a ``TypedDict`` of the same fields under the same rules: a message
    read into a plain dict, with no instance to build and none to serialize. A field
    with a default may be absent (it is then not in the dict); one sent as null is None."""
    annotated: Any = Annotated  # the forms are built at run time, from the model's fields
    typed_dict: Any = TypedDict
    fields: dict[str, Any] = {}
    for name, info in model.model_fields.items():
        said = [Field(description=info.description)] if info.description else []
        kind = annotated[(info.annotation, *info.metadata, *said)]
        fields[name] = kind if info.is_required() else NotRequired[kind]
    form = typed_dict(f"{model.__name__}Doc", fields)
    form.__doc__ = f"{model.__name__}, read as a plain dict. " + (model.__doc__ or "").strip()
    form.__pydantic_config__ = ConfigDict(extra="ignore")  # unknown fields, as WireModel
    return form


#: A :class:`Sample` read as a plain dict (the server's stored form of a sample once its
#: nulls are left out): the server reads ``update_param``'s samples so, sparing a model
#: and its serializer for each of the most numerous values it takes.
SampleDoc = _doc_form(Sample)
