"""The error envelope every 4xx/5xx answer carries, and the words of a refusal.

:func:`error_text` is a field's message in a 422 (``details``: ``FieldError``);
:func:`unreadable_json` says why a body or frame could not be read at all.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Mapping
from typing import Any

from pydantic import BaseModel

from fleet_protocol.common import ID_PATTERN, ID_RULE
from fleet_protocol.values import MAX_INT, MAX_JSON_DEPTH, MIN_INT

__all__ = [
    "NOT_READ",
    "ErrorBody",
    "ErrorEnvelope",
    "FieldError",
    "LongInteger",
    "error_text",
    "long_integers",
    "read_leniently",
    "unreadable_json",
]


class FieldError(BaseModel):
    field: str
    message: str


class ErrorBody(BaseModel):
    code: str
    message: str
    details: Any = None


class ErrorEnvelope(BaseModel):
    error: ErrorBody


#: Why a body or frame nested past what its JSON reader goes (pydantic's parser: 200
#: levels; Python's ``json``: its recursion limit) cannot be read.
_TOO_DEEP_MSG = (
    f"nested too deep to be read (a value is nested at most {MAX_JSON_DEPTH} levels: "
    "docs/limits.md)"
)


def error_text(err: Mapping[str, Any]) -> str:
    """A pydantic error's message for a 422 (without pydantic's "Value error, " prefix).
    A length bound on an optional string (``Text | None``) is checked by pydantic's
    generic length rule, whose message counts "items": it is told in characters."""
    ctx = err.get("ctx") or {}
    if err.get("type") == "too_long" and isinstance(err.get("input"), str):
        return f"String should have at most {ctx.get('max_length')} characters"
    if err.get("type") == "too_short" and isinstance(err.get("input"), str):
        return f"String should have at least {ctx.get('min_length')} characters"
    if err.get("type") == "string_pattern_mismatch" and ctx.get("pattern") == ID_PATTERN:
        return f"an id or a name is {ID_RULE}"
    if err.get("type") == "extra_forbidden":
        return (
            "not a field of this body (this body refuses fields it does not know: "
            "a misspelt one would otherwise pass as a change not made)"
        )
    return str(err.get("msg", "invalid value")).removeprefix("Value error, ")


class LongInteger:
    """An integer written with more digits than Python reads (``sys.get_int_max_str_digits``,
    4,300 by default), as :func:`read_leniently` reads it: far outside 64-bit anyway."""

    __slots__ = ("digits",)

    def __init__(self, digits: int) -> None:
        self.digits = digits


def _integer(literal: str) -> int | LongInteger:
    try:
        return int(literal)
    except ValueError:  # past Python's digit limit: left unread (reading it is quadratic)
        return LongInteger(len(literal.lstrip("-")))


#: What :func:`read_leniently` answers for a text that is not JSON at all.
NOT_READ: Any = object()


def read_leniently(text: str | bytes) -> Any:
    """``text`` read as Python's ``json`` reads it, but an integer too long for Python to
    read is a :class:`LongInteger` where the reader would refuse the whole text (so the
    refusal can name its field); :data:`NOT_READ` when it is not JSON all the same.
    Slower than ``json.loads``: for a text already refused."""
    try:
        return json.loads(text)
    except RecursionError:
        return NOT_READ
    except ValueError as exc:
        if "integer string conversion" not in str(exc):
            return NOT_READ
    try:
        return json.loads(text, parse_int=_integer)
    except (ValueError, RecursionError):
        return NOT_READ


def long_integers(value: Any) -> list[FieldError]:
    """The field (``params.x``, ``ops.0.samples.3.seq``) of each :class:`LongInteger` in
    a value :func:`read_leniently` read, with the rule it breaks."""
    found: list[FieldError] = []
    todo: list[tuple[str, Any]] = [("", value)]
    while todo:
        path, item = todo.pop()
        if isinstance(item, LongInteger):
            message = (
                f"an integer must lie within signed 64-bit ({MIN_INT} to {MAX_INT}); "
                f"this one has {item.digits:,} digits"
            )
            found.append(FieldError(field=path or "body", message=message))
        elif isinstance(item, dict):
            todo.extend((f"{path}.{k}" if path else str(k), v) for k, v in item.items())
        elif isinstance(item, list):
            todo.extend((f"{path}.{i}" if path else str(i), v) for i, v in enumerate(item))
    found.reverse()  # in the order written
    return found


def unreadable_json(error: object, raw: object = None) -> str:
    """Why a text a JSON reader refused cannot be read, to follow "the body is" or "the
    frame is": nested too deep, not valid UTF-8, or not valid JSON. ``error`` is the
    reader's exception (Python's ``json``) or its message (pydantic's ``json_invalid``);
    ``raw``, the bytes it read when known (pydantic's parser calls a byte that is not
    UTF-8 outside a string an unexpected character)."""
    if isinstance(raw, bytes):
        try:
            raw.decode("utf-8")
        except UnicodeDecodeError:
            return "not valid UTF-8"
    text = str(error)
    if isinstance(error, RecursionError) or "recursion limit exceeded" in text:
        return _TOO_DEEP_MSG
    if isinstance(error, UnicodeDecodeError) or "invalid unicode code point" in text:
        return "not valid UTF-8"
    if "integer string conversion" in text:  # Python's json, past its digit limit
        return (
            f"not read: it holds an integer of more than {sys.get_int_max_str_digits():,} "
            "digits (an integer lies within signed 64-bit: docs/limits.md)"
        )
    return "not valid JSON"
