"""The pure parts of the WebSocket link: URLs, op ids, pushes, batches, close codes.

No I/O here; ``vehicle_client.transport.ws`` and ``ws_ops`` are the shell around it.
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Iterable, Iterator
from typing import Annotated, Any

from pydantic import Field, TypeAdapter, ValidationError

from fleet_protocol.links import (
    CLOSE_FORBIDDEN,
    CLOSE_REPLACED,
    CLOSE_UNAUTHORIZED,
    MAX_TEXT_FRAME_BYTES,
    websocket_url,
)
from fleet_protocol.ws import MAX_BATCH_OPS, AckPush, Push
from vehicle_client.errors import (
    CHECK_TOKEN,
    FatalError,
    Refused,
    RetryableError,
    SessionLost,
    TokenRefused,
    refused_fields,
)

__all__ = [
    "AnyPush",
    "IdSource",
    "PushError",
    "ack_error",
    "batches",
    "close_error",
    "op_frame",
    "parse_push",
    "ws_url",
]


#: Every push the server sends (``fleet_protocol.ws.Push``, the one list), told apart by op.
AnyPush = Annotated[Push, Field(discriminator="op")]
_push_adapter: TypeAdapter[Any] = TypeAdapter(AnyPush)


class PushError(ValueError):
    """A frame from the server that is not a push this agent knows."""


def parse_push(frame: str | bytes) -> Any:
    """One push (``AckPush``, ``CommandPush``...), or ``PushError``."""
    try:
        return _push_adapter.validate_json(frame)
    except ValidationError as exc:
        first = exc.errors(include_url=False)[0]
        where = ".".join(str(p) for p in first["loc"]) or "frame"
        raise PushError(f"unreadable push ({where}: {first['msg']})") from None


def ws_url(server: str, path: str = "/ws/vehicle") -> str:
    """``http://host:port/prefix`` -> ``ws://host:port/prefix/ws/vehicle`` (https -> wss)."""
    try:
        return websocket_url(server, path)
    except ValueError:
        raise FatalError(f"--server must be an http(s) URL, got {server!r}") from None


class IdSource:
    """Op ids unique on one link: a short prefix per link, then a counter."""

    def __init__(self, prefix: str = "a") -> None:
        self.prefix = prefix
        self._n = itertools.count(1)

    def next(self) -> str:
        return f"{self.prefix}{next(self._n)}"


def op_frame(op: dict[str, Any]) -> str:
    """An op dict as a compact JSON text frame."""
    return json.dumps(op, separators=(",", ":"))


def op_frame_bytes(op: dict[str, Any], shown: int) -> int:
    """The bytes ``op`` takes as the link sends it (ASCII JSON); 0, not measured, when
    what it carries (``shown`` characters) is far from the frame's bound, as most are: a
    character is at most 6 bytes escaped."""
    if 6 * shown + 512 < MAX_TEXT_FRAME_BYTES:
        return 0
    return len(op_frame(op))


def batches(ops: Iterable[dict[str, Any]], limit: int = MAX_BATCH_OPS) -> Iterator[str]:
    """Frames for queued ops: one op alone as itself, more as ``batch`` frames of at most
    ``limit`` ops each (the batch itself carries no id: its ops are acked one by one)."""
    pending = list(ops)
    for start in range(0, len(pending), limit):
        chunk = pending[start : start + limit]
        if len(chunk) == 1:
            yield op_frame(chunk[0])
        else:
            yield op_frame({"op": "batch", "ops": chunk})


def close_error(code: int | None, reason: str | None) -> RetryableError | FatalError:
    """What a closed socket means for the agent: fatal for 4401/4403/4409, else retry."""
    why = f" ({reason})" if reason else ""
    if code == CLOSE_UNAUTHORIZED:
        return TokenRefused(f"the server refused the token{why}; " + CHECK_TOKEN)
    if code == CLOSE_FORBIDDEN:
        return FatalError(f"the token may not act for this vehicle{why}")
    if code == CLOSE_REPLACED:
        return FatalError(
            "another agent connected for this vehicle and replaced this one"
            f"{why}: stop the other agent (two agents for one vehicle fight over it)"
        )
    return RetryableError(f"the server closed the WebSocket (code {code}){why}")


def ack_error(ack: AckPush, what: str) -> RetryableError | FatalError:
    """The error for a refused op, sorted like the HTTP transport's status codes."""
    error = ack.error
    code = error.code if error is not None else ""
    text = f"{what}: {code}: {error.message if error else 'refused'}"
    if code == "unauthorized":
        return TokenRefused(f"the server refused the token ({text}); " + CHECK_TOKEN)
    if code == "forbidden":
        return FatalError(f"the token may not act for this vehicle ({text})")
    if code in ("not_found", "instance_finished"):
        return SessionLost(text)
    if code == "invalid":
        return Refused(text, refused_fields(error.details if error is not None else None))
    return RetryableError(text)
