"""The error envelope every 4xx/5xx answer carries, and the words of a refusal.

:func:`error_text` is a field's message in a 422 (``details``: ``FieldError``);
:func:`unreadable_json` says why a body or frame could not be read at all.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from pydantic import BaseModel

from fleet_protocol.values import MAX_JSON_DEPTH

__all__ = ["ErrorBody", "ErrorEnvelope", "FieldError", "error_text", "unreadable_json"]


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
    return str(err.get("msg", "invalid value")).removeprefix("Value error, ")


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
    return "not valid JSON"
