"""Request-size limit as pure ASGI middleware: 413 before the body is parsed."""

from __future__ import annotations

import json
from typing import Any

from starlette.types import ASGIApp, Message, Receive, Scope, Send


def _envelope(limit: int) -> bytes:
    return json.dumps(
        {
            "error": {
                "code": "too_large",
                "message": f"the request body is larger than {limit} bytes",
                "details": {"max_body_bytes": limit},
            }
        }
    ).encode()


class BodyLimit:
    """413 for a body over ``max_bytes``: at once from its ``Content-Length``, or, for a
    body sent without one (chunked), once the bytes read pass the bound, before the app
    has seen any of it (the body is gathered first, at most ``max_bytes`` of it)."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        length = None
        for name, value in scope.get("headers", []):
            if name == b"content-length":
                try:
                    length = int(value)
                except ValueError:
                    length = None
        if length is not None:
            if length > self.max_bytes:
                await self._reject(send)
                return
            await self.app(scope, self._counted(receive), send)
            return
        gathered = await self._gather(receive)
        if gathered is None:
            await self._reject(send)
            return
        await self.app(scope, replay(gathered, receive), send)

    def _counted(self, receive: Receive) -> Receive:
        """A body that lies about its length is cut off at the bound all the same."""
        seen = 0

        async def limited() -> Message:
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.max_bytes:
                    return {"type": "http.disconnect"}
            return message

        return limited

    async def _gather(self, receive: Receive) -> list[Message] | None:
        """The request's messages up to the end of its body; None past the bound."""
        messages: list[Message] = []
        seen = 0
        while True:
            message = await receive()
            messages.append(message)
            if message["type"] != "http.request":
                return messages  # the client went
            seen += len(message.get("body", b""))
            if seen > self.max_bytes:
                return None
            if not message.get("more_body", False):
                return messages

    async def _reject(self, send: Send) -> None:
        body = _envelope(self.max_bytes)
        headers: list[Any] = [
            (b"content-type", b"application/json"),
            (b"content-length", str(len(body)).encode()),
        ]
        await send({"type": "http.response.start", "status": 413, "headers": headers})
        await send({"type": "http.response.body", "body": body})


def replay(messages: list[Message], receive: Receive) -> Receive:
    """A ``receive`` that hands out ``messages`` (read from the request already) first,
    then the request's own."""
    pending = list(messages)

    async def replayed() -> Message:
        if pending:
            return pending.pop(0)
        return await receive()

    return replayed
