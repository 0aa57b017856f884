"""Values stored before a rule existed, made safe to send.

The wire models (:mod:`fleet_protocol.values`) refuse what JSON or the store
cannot hold as it comes in; a value an older version stored may still break a
rule. :func:`json_safe` makes one into a value JSON can hold, for the encoders
that must still send it, and :data:`ServedObject` escapes a free-form field
that way only when serialising it failed.
"""

from __future__ import annotations

import json
import math
from datetime import datetime
from typing import Annotated, Any

from pydantic import SerializerFunctionWrapHandler, WrapSerializer
from pydantic_core import PydanticSerializationError

from fleet_protocol.text import SURROGATE
from fleet_protocol.values import MAX_INT, MAX_JSON_DEPTH, MIN_INT

__all__ = ["ServedObject", "ServedObjects", "json_safe", "safe_dumps"]


def json_safe(value: Any, depth: int = 0) -> Any:
    """``value`` with what JSON cannot hold replaced: integers past signed 64-bit as
    strings, NaN and Infinity as null, lone surrogates as U+FFFD, keys as strings, other
    objects as their ``str``; past :data:`MAX_JSON_DEPTH` * 4 levels, a string."""
    if isinstance(value, str):
        return SURROGATE.sub("\ufffd", value) if not value.isascii() else value
    if isinstance(value, bool) or value is None:
        return value
    if isinstance(value, int):
        return int(value) if MIN_INT <= value <= MAX_INT else str(value)
    if isinstance(value, float):
        return float(value) if math.isfinite(value) else None
    if depth > 4 * MAX_JSON_DEPTH:
        return "…"
    if isinstance(value, dict):
        return {json_safe(_key_text(k)): json_safe(v, depth + 1) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v, depth + 1) for v in value]
    if isinstance(value, datetime):
        from fleet_protocol.common import format_ts  # common imports this module

        try:
            return format_ts(value)
        except (OverflowError, ValueError):
            return value.isoformat()
    return json_safe(str(value), depth)


def _serve_escaped(value: Any, handler: SerializerFunctionWrapHandler) -> Any:
    try:
        return handler(value)
    except (PydanticSerializationError, UnicodeError):
        return handler(json_safe(value))


#: Free-form fields the server fills from the store (``Event.data``,
#: ``GetParamResult.params``, ``TelemetryPage.samples``...): a value stored before a rule
#: existed that JSON cannot hold is sent escaped (:func:`json_safe`) instead of failing
#: the whole answer. One call per field; the walk only when serialising failed.
ServedObject = Annotated[dict[str, Any], WrapSerializer(_serve_escaped, return_type=dict[str, Any])]
ServedObjects = Annotated[
    list[dict[str, Any]], WrapSerializer(_serve_escaped, return_type=list[dict[str, Any]])
]


def _key_text(key: Any) -> str:
    return key if isinstance(key, str) else str(key)


def safe_dumps(value: Any) -> str:
    """Compact JSON text of :func:`json_safe` ``(value)``: what the encoders fall back to."""
    return json.dumps(json_safe(value), separators=(",", ":"), ensure_ascii=False)
