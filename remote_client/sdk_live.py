"""The SDK's live calls, on ``/ws/client``: follow topics, publish on one. A part of
:class:`~remote_client.sdk.FleetClient`."""

from __future__ import annotations

import json
from collections.abc import AsyncGenerator
from typing import Any

import websockets

from fleet_protocol.links import (
    CLOSE_FORBIDDEN,
    CLOSE_RECONNECT,
    CLOSE_UNAUTHORIZED,
    MAX_BINARY_FRAME_BYTES,
    websocket_url,
)
from remote_client.sdk_session import Body, FleetApiError, OneOrMany, Session, listed

__all__ = ["LiveCalls"]

#: WebSocket close codes that refuse the token or the socket, as HTTP statuses.
REFUSING_CLOSE_CODES = {CLOSE_UNAUTHORIZED: 401, CLOSE_FORBIDDEN: 403}
#: The HTTP status an error code has on the HTTP routes (a refused op is acked with the code).
STATUS_OF_CODE = {
    "unauthorized": 401, "forbidden": 403, "not_found": 404, "invalid": 422, "rate_limited": 429,
    "too_large": 413, "unavailable": 503,
}  # fmt: skip


#: How many times in a row, with no event between, :meth:`LiveCalls.events` opens its
#: socket again when told to (4012); the server does not say so again and again, but a
#: bound holds.
_REOPENS = 20


class LiveCalls(Session):
    """Topics on the client WebSocket (``docs/live.md``)."""

    async def publish(self, topic: str, data: Any) -> None:
        """Publish ``data`` (any JSON) on ``topic`` once, to its subscribers (a user writes
        under ``user/<its name>/``); returns once the server has acked it. Refused:
        :class:`FleetApiError` (``forbidden``, ``invalid``...)."""
        op: Body = {"op": "publish", "id": "publish", "topic": topic, "data": data}
        try:
            frame = json.dumps(op, allow_nan=False)
        except ValueError as exc:  # NaN, an infinity: no JSON number
            raise FleetApiError(422, "invalid", f"not sent: {exc}") from None
        async with self._socket() as ws:
            try:
                await ws.send(frame)
                async for text in ws:
                    if isinstance(text, str) and _acked(json.loads(text), "publish"):
                        return
            except websockets.ConnectionClosed as exc:
                _raise_refusal(exc)
                raise

    async def events(
        self, topics: OneOrMany, *, throttle_ms: int = 0
    ) -> AsyncGenerator[Body, None]:
        """Subscribe on ``/ws/client`` and yield its ``event`` and ``lagging`` pushes (each
        topic's current state first, ``snapshot: true``) until the server closes.

        A refused token or subscription raises :class:`FleetApiError`; a lost link ends
        the iteration (``websockets.ConnectionClosed`` is not raised). A socket closed
        because the user's rights changed (4012: connect again) is opened again and the
        topics subscribed again, each one's state coming first once more; a subscription
        the new rights refuse raises.
        """
        subscribe: Body = {"op": "subscribe", "id": "events", "topics": listed(topics)}
        if throttle_ms:
            subscribe["throttle_ms"] = throttle_ms
        reopens = 0
        while True:
            async with self._socket() as ws:
                try:
                    await ws.send(json.dumps(subscribe))
                    async for frame in ws:
                        if not isinstance(frame, str):
                            continue  # media frames: not for this iterator
                        push = json.loads(frame)
                        _acked(push, "events")  # a refusal raises
                        if push.get("op") in ("event", "lagging"):
                            reopens = 0
                            yield push
                except websockets.ConnectionClosed as exc:
                    _raise_refusal(exc)
                    told = exc.rcvd is not None and exc.rcvd.code == CLOSE_RECONNECT
                    if told and reopens < _REOPENS:
                        reopens += 1
                        continue
            return

    def _socket(self) -> Any:
        return websockets.connect(
            websocket_url(self.server, "/ws/client"),
            additional_headers=self._headers,
            open_timeout=30,
            # the largest push: a media frame, or the largest publish with its source
            # and time added (websockets' default, 1 MiB, refused that one)
            max_size=MAX_BINARY_FRAME_BYTES,
        )


def _acked(push: Body, op_id: str) -> bool:
    """Whether ``push`` is the ack of ``op_id``; a refusal raises :class:`FleetApiError`."""
    if push.get("op") != "ack" or push.get("id") != op_id:
        return False
    if not push.get("ok"):
        error = push.get("error") or {}
        code = error.get("code", "refused")
        status = STATUS_OF_CODE.get(code, 409)
        raise FleetApiError(status, code, error.get("message", ""), error.get("details"))
    return True


def _raise_refusal(exc: websockets.ConnectionClosed) -> None:
    """A socket the server closed to refuse the token: :class:`FleetApiError`."""
    closing = REFUSING_CLOSE_CODES.get(exc.rcvd.code) if exc.rcvd else None
    if closing is not None and exc.rcvd is not None:
        raise FleetApiError(closing, "refused", exc.rcvd.reason) from None
