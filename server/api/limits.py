"""Request limits as pure ASGI middleware, before anything is parsed: 413 for a body over
the bound; 422 for a JSON body that is not UTF-8 though Python's JSON reader would take
it, and for a query parameter given more than once (no parameter of this API takes a
list: Starlette would keep the last value, and a filter named twice would drop one).
A JSON body's chunks are kept in the scope as read (:func:`body_kept`), for a refusal
that must name a field of a body Python's JSON reader could not read."""

from __future__ import annotations

import json
from typing import Any
from urllib.parse import unquote_plus

from starlette.types import ASGIApp, Message, Receive, Scope, Send

#: The scope's key for a JSON body's chunks as read (the same bytes objects, not copies):
#: a refusal of a body Python's reader could not read names the field from them.
BODY_KEPT = "fleet.body"


def body_kept(scope: Scope) -> bytes | None:
    """The JSON body of the request as read so far (None: not a JSON body)."""
    kept = scope.get(BODY_KEPT)
    return None if kept is None else b"".join(kept)


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


_NOT_UTF8 = "the body is not valid UTF-8 (it reads as UTF-16 or UTF-32: send UTF-8)"


def _wide(start: bytes) -> bool:
    """Whether a body's first bytes are UTF-16 or UTF-32, which Python's ``json.loads``
    reads (it guesses them from a byte order mark or the zero bytes of the first
    character) where JSON on this server is UTF-8 (no JSON text in UTF-8 starts with a
    zero byte or those marks). A zero in the first two bytes, as ``json.detect_encoding``
    looks: every JSON text in UTF-16 or UTF-32 has one there, a gzip body (``1f 8b 08 00``)
    none, and it is not valid UTF-8, not text in another encoding."""
    return start[:2] in (b"\xff\xfe", b"\xfe\xff") or b"\x00" in start[:2]


def _repeated(query: bytes) -> str | None:
    """The first query parameter named twice (names as Starlette decodes them)."""
    seen: set[bytes | str] = set()
    for part in query.split(b"&"):
        raw = part.partition(b"=")[0]
        if not raw:
            continue
        name: bytes | str = raw
        if b"%" in raw or b"+" in raw:
            name = unquote_plus(raw.decode("latin-1"))
        else:
            name = raw.decode("latin-1")
        if name in seen:
            return str(name)
        seen.add(name)
    return None


def _refusal(field: str, message: str) -> bytes:
    error = {
        "code": "invalid",
        "message": message,
        "details": [{"field": field, "message": message}],
    }
    return json.dumps({"error": error}).encode()


def _encoded(encoding: str) -> bytes:
    """The 415 of a body sent compressed (the server reads every body as it comes)."""
    message = (
        f"the body is sent with Content-Encoding: {encoding[:40]}; the server reads bodies "
        "as they are: send it uncompressed, without Content-Encoding"
    )
    error = {
        "code": "unsupported_media_type",
        "message": message,
        "details": [{"field": "Content-Encoding", "message": message}],
    }
    return json.dumps({"error": error}).encode()


def _json_body(scope: Scope) -> bool:
    for name, value in scope.get("headers", []):
        if name == b"content-type":
            return b"json" in value.lower()
    return False


class BodyLimit:
    """413 for a body over ``max_bytes``: at once from its ``Content-Length``, or, for a
    body sent without one (chunked), once the bytes read pass the bound, before the app
    has seen any of it (the body is gathered first, at most ``max_bytes`` of it). 422
    naming ``body`` for a JSON body in UTF-16 or UTF-32 (seen in its first bytes)."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        if scope["query_string"] and (twice := _repeated(scope["query_string"])):
            said = f"{twice} is given more than once: give it once"
            if twice == "names":  # get_param's names: the contract's one list
                said += ", as a comma list (names=a,b)"
            await _answer(send, 422, _refusal(twice, said))
            return
        length = None
        encoding = b""
        for name, value in scope.get("headers", []):
            if name == b"content-length":
                try:
                    length = int(value)
                except ValueError:
                    length = None
            elif name == b"content-encoding":
                encoding = value.strip().lower()
        if encoding not in (b"", b"identity"):
            await _answer(send, 415, _encoded(encoding.decode("latin-1")))
            return
        if length is not None:
            if length > self.max_bytes:
                await self._reject(send)
                return
            first = None
            if length and _json_body(scope):
                first = await receive()
                if _wide(first.get("body", b"")):
                    await self._refuse_wide(send)
                    return
                scope[BODY_KEPT] = []
            await self.app(scope, self._counted(receive, first, scope.get(BODY_KEPT)), send)
            return
        gathered = await self._gather(receive)
        if gathered is None:
            await self._reject(send)
            return
        if _json_body(scope):
            if _wide(gathered[0].get("body", b"")):
                await self._refuse_wide(send)
                return
            scope[BODY_KEPT] = [m.get("body", b"") for m in gathered]
        await self.app(scope, replay(gathered, receive), send)

    def _counted(
        self, receive: Receive, first: Message | None, kept: list[bytes] | None
    ) -> Receive:
        """A body that lies about its length is cut off at the bound all the same.
        ``first``: the request's first message, read already; ``kept``: where a JSON
        body's chunks are kept (:data:`BODY_KEPT`)."""
        seen = 0

        async def limited() -> Message:
            nonlocal seen, first
            if first is not None:
                message, first = first, None
            else:
                message = await receive()
            if message["type"] == "http.request":
                if kept is not None:
                    kept.append(message.get("body", b""))
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
        await _answer(send, 413, _envelope(self.max_bytes))

    async def _refuse_wide(self, send: Send) -> None:
        await _answer(send, 422, _refusal("body", _NOT_UTF8))


async def _answer(send: Send, status: int, body: bytes) -> None:
    headers: list[Any] = [
        (b"content-type", b"application/json"),
        (b"content-length", str(len(body)).encode()),
    ]
    await send({"type": "http.response.start", "status": status, "headers": headers})
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
