"""JSON text frames for the sockets, encoded with orjson (the hot path of every push)."""

from __future__ import annotations

import json
from typing import Any

import orjson

__all__ = ["dumps"]


def dumps(value: Any) -> str:
    """Compact JSON text; what orjson refuses (integers past 64 bits) goes through ``json``."""
    try:
        return orjson.dumps(value).decode()
    except TypeError:
        return json.dumps(value, separators=(",", ":"), default=str)
