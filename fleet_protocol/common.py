"""Shared field types: timestamps, identifiers, positions, samples."""

from __future__ import annotations

import time
from datetime import UTC, datetime
from typing import Annotated, Any

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, PlainSerializer

__all__ = [
    "ID_PATTERN",
    "MAX_SAMPLE_DATA_BYTES",
    "Identifier",
    "LatLon",
    "Latitude",
    "Longitude",
    "Sample",
    "Timestamp",
    "WireModel",
    "format_ts",
    "now_ts",
    "parse_ts",
    "utcnow",
]

#: Identifiers (vehicles, users, gateways) become topic segments
#: (``vehicle/<id>/telemetry``), so they follow the topic grammar.
ID_PATTERN = r"^[a-z0-9][a-z0-9_-]{0,63}$"

#: Bound on the JSON size of one sample's free-form ``data``.
MAX_SAMPLE_DATA_BYTES = 8192


def utcnow() -> datetime:
    return datetime.now(UTC)


def _as_utc(value: datetime) -> datetime:
    if value.tzinfo is None:
        return value.replace(tzinfo=UTC)
    return value.astimezone(UTC)


def format_ts(value: datetime) -> str:
    """ISO 8601 UTC with milliseconds, the contract's one time format."""
    if value.tzinfo is not UTC:
        value = _as_utc(value)
    # "2026-05-01T12:00:00.000+00:00" less its offset: isoformat is the fastest spelling.
    return value.isoformat(timespec="milliseconds")[:23] + "Z"


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


Timestamp = Annotated[
    datetime,
    AfterValidator(_as_utc),
    PlainSerializer(format_ts, return_type=str, when_used="json"),
]
Identifier = Annotated[str, Field(pattern=ID_PATTERN, examples=["usv-1"])]
Latitude = Annotated[float, Field(ge=-90, le=90, allow_inf_nan=False)]
Longitude = Annotated[float, Field(ge=-180, le=180, allow_inf_nan=False)]


class WireModel(BaseModel):
    """Base of every message: unknown fields are ignored (clients may be newer)."""

    model_config = ConfigDict(extra="ignore", populate_by_name=True)


class LatLon(WireModel):
    lat: Latitude
    lon: Longitude


def _bounded_data(value: dict[str, Any] | None) -> dict[str, Any] | None:
    if value is None:
        return None
    import json

    size = len(json.dumps(value, separators=(",", ":"), default=str))
    if size > MAX_SAMPLE_DATA_BYTES:
        raise ValueError(f"data is {size} bytes, at most {MAX_SAMPLE_DATA_BYTES} are accepted")
    return value


class Sample(WireModel):
    """One telemetry sample. ``seq`` rises strictly per vehicle."""

    seq: int = Field(ge=1, le=2**62, description="per vehicle, rising; 0 means none yet")
    ts: Timestamp
    lat: Latitude
    lon: Longitude
    depth_m: float | None = Field(default=None, allow_inf_nan=False)
    heading_deg: float | None = Field(default=None, ge=0, le=360, allow_inf_nan=False)
    speed_mps: float | None = Field(default=None, ge=0, le=200, allow_inf_nan=False)
    battery_pct: float | None = Field(default=None, ge=0, le=100, allow_inf_nan=False)
    data: Annotated[dict[str, Any] | None, AfterValidator(_bounded_data)] = None
