"""JSON text frames for the sockets, encoded with orjson (the hot path of every push)."""

from __future__ import annotations

from typing import Any

import orjson

from fleet_protocol.served import safe_dumps

__all__ = ["dumps"]


def dumps(value: Any) -> str:
    """Compact JSON text. What orjson refuses (an integer past 64 bits, a lone surrogate, a
    key that is not a string: data stored by an older version) is sent escaped, never
    refused: :func:`fleet_protocol.served.json_safe`. NaN and Infinity become null."""
    try:
        return orjson.dumps(value).decode()
    except TypeError:  # orjson.JSONEncodeError is one
        return safe_dumps(value)
