"""One handler renders every error as the contract's envelope."""

from __future__ import annotations

import logging
import re
from collections.abc import Sequence
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import ClientDisconnect
from starlette.routing import BaseRoute, Match, Mount
from starlette.types import Scope

from fleet_protocol.errors import (
    NOT_READ,
    FieldError,
    error_text,
    long_integers,
    read_leniently,
    unreadable_json,
)
from fleet_protocol.text import escape_controls, shown_text
from server.api.limits import body_kept
from server.api.responses import SafeJSONResponse
from server.errors import FleetError, RateLimited, Unavailable

log = logging.getLogger("fleet.api")

_ARGS_PART = re.compile(r"^(args(?:\.[\w\d]+)*): (.*)$")
_HTTP_CODES = {
    400: "bad_request",
    401: "unauthorized",
    403: "forbidden",
    404: "not_found",
    405: "method_not_allowed",
    406: "not_acceptable",
    409: "conflict",
    413: "too_large",
    415: "unsupported_media_type",
    422: "invalid",
    429: "rate_limited",
    503: "unavailable",
}


#: The longest message an answer carries: one that quotes what a client sent (an id in a
#: path) does not send it all back.
MAX_MESSAGE_CHARS = 300


def said(message: str) -> str:
    """A message as an answer carries it: control characters shown as escapes (``\\x00``),
    cut at :data:`MAX_MESSAGE_CHARS`."""
    message = escape_controls(message)
    if len(message) > MAX_MESSAGE_CHARS:
        message = message[: MAX_MESSAGE_CHARS - 1] + "…"
    return message


def envelope(
    status: int, code: str, message: str, details: Any = None, headers: dict[str, str] | None = None
) -> JSONResponse:
    return SafeJSONResponse(
        {"error": {"code": code, "message": said(message), "details": details}},
        status_code=status,
        headers=headers,
    )


def field_errors(errors: list[dict[str, Any]]) -> list[dict[str, str]]:
    """Pydantic errors as ``[{field, message}]``; request location prefixes dropped."""
    out: list[dict[str, str]] = []
    for err in errors:
        loc = [str(p) for p in err.get("loc", ())]
        if loc and loc[0] in ("body", "query", "path", "header"):
            loc = loc[1:]
        # A discriminated/union tag in the path is noise for the reader.
        loc = [p for p in loc if not p.startswith("function-")]
        name = shown_text(".".join(loc)) or "body"
        msg = error_text(err)
        # Command args are validated as one value: split their messages by field.
        parts = [_ARGS_PART.match(p) for p in msg.split("; ")]
        if parts and all(parts):
            for m in parts:
                assert m is not None
                out.append({"field": f"{name}.{m.group(1)}", "message": m.group(2)})
            continue
        if err.get("type") == "json_invalid":
            why = unreadable_json(err.get("ctx", {}).get("error", ""))
            name, msg = "body", f"the body is {why}"
        out.append({"field": name, "message": msg})
    return out


def _not_read_as_json(errors: list[dict[str, Any]], content_type: str | None) -> bool:
    """Whether the body was refused whole because it came without a JSON content type
    (``curl -d`` sends ``application/x-www-form-urlencoded``): FastAPI then does not
    read it as JSON, and the model finds no object."""
    media = (content_type or "").partition(";")[0].strip().lower()
    return (
        bool(errors)
        and all(tuple(err.get("loc", ())) == ("body",) for err in errors)
        and not (media == "application/json" or media.endswith("+json"))
    )


#: The methods a path may take (what a 405's ``Allow`` may list).
_METHODS = ("DELETE", "GET", "HEAD", "PATCH", "POST", "PUT")


def path_methods(routes: Sequence[BaseRoute], scope: Scope) -> list[str]:
    """The methods the routes (not the mounted files) take at a request's path, together:
    a path may have a route per method, and Starlette's 405 names only the first one's.
    HEAD wherever GET (the app answers it as GET without the body: ``HEAD_SCOPE_KEY``)."""
    taken = [
        method
        for method in _METHODS
        if any(
            not isinstance(route, Mount)
            and route.matches({**scope, "method": method})[0] is Match.FULL
            for route in routes
        )
    ]
    if "GET" in taken and "HEAD" not in taken:
        taken.insert(taken.index("GET") + 1, "HEAD")
    return taken


#: Set in the scope of a HEAD request the app answers as a GET (the server writes no body).
HEAD_SCOPE_KEY = "fleet.head"


def _long_integers(body: object) -> list[FieldError]:
    """The fields of the integers too long for Python's json to read in a JSON body; []
    when it has none, or is not known (None)."""
    value = read_leniently(body) if isinstance(body, bytes | str) else NOT_READ
    return [] if value is NOT_READ else long_integers(value)


def _named(long: list[FieldError]) -> JSONResponse:
    fields = ", ".join(d.field for d in long)
    return envelope(422, "invalid", f"invalid input: {fields}", [d.model_dump() for d in long])


def install(app: FastAPI) -> None:
    @app.exception_handler(FleetError)
    async def _fleet(_: Request, exc: FleetError) -> JSONResponse:
        headers = None
        if isinstance(exc, RateLimited | Unavailable):
            headers = {"Retry-After": str(max(1, round(exc.retry_after_s)))}
        return envelope(exc.status, exc.code, exc.message, exc.details, headers)

    @app.exception_handler(RequestValidationError)
    async def _invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = list(exc.errors())
        if errors and errors[0].get("type") == "json_invalid":  # the body was not read
            if long := _long_integers(exc.body):  # pydantic's parser: the login's body
                return _named(long)
            why = unreadable_json(errors[0].get("ctx", {}).get("error", ""), exc.body)
            message = f"the body is {why}"
            return envelope(422, "invalid", message, [{"field": "body", "message": message}])
        if _not_read_as_json(errors, request.headers.get("content-type")):
            message = (
                "the body is read as JSON only when sent with Content-Type: application/json "
                f"(this one: {request.headers.get('content-type') or 'none'})"
            )
            return envelope(422, "invalid", message, [{"field": "body", "message": message}])
        details = field_errors(errors)
        fields = ", ".join(d["field"] for d in details)
        return envelope(422, "invalid", f"invalid input: {fields}", details)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        cause = exc.__cause__
        if exc.status_code == 400 and isinstance(cause, ValueError | RecursionError):
            # FastAPI's "error parsing the body": a body Python's json could not read
            # (not UTF-8, nested past its recursion limit, an integer past its digit
            # limit), as any other unreadable body; such an integer's field is named.
            if long := _long_integers(body_kept(request.scope)):  # BodyLimit kept it
                return _named(long)
            message = "the body is " + unreadable_json(cause)
            return envelope(422, "invalid", message, [{"field": "body", "message": message}])
        code = _HTTP_CODES.get(exc.status_code, "error")
        message = exc.detail if isinstance(exc.detail, str) else code.replace("_", " ")
        headers = getattr(exc, "headers", None)
        if exc.status_code == 405:
            allowed = path_methods(request.app.router.routes, request.scope)
            if allowed:  # a route's: the methods of every route of the path, not its own
                headers = {**(headers or {}), "Allow": ", ".join(allowed)}
                method = "HEAD" if request.scope.get(HEAD_SCOPE_KEY) else request.method
                message = f"{method} is not allowed here; this path takes {', '.join(allowed)}"
        return envelope(exc.status_code, code, message, headers=headers)

    @app.exception_handler(ClientDisconnect)
    async def _gone(_: Request, exc: ClientDisconnect) -> JSONResponse:
        # The client went away while its body was read: nobody reads this answer, and
        # it is no fault of the server's (no 500, no traceback in the log).
        log.info("a client closed its connection before its request was read")
        message = "the connection closed before the request was read"
        return envelope(400, "bad_request", message)

    @app.exception_handler(Exception)
    async def _unexpected(_: Request, exc: Exception) -> JSONResponse:
        log.exception("unexpected error", exc_info=exc)
        return envelope(500, "internal", "the server failed on this request; it is logged")


async def no_socket_here(scope: Scope, send: Any, live_paths: Sequence[str]) -> None:
    """A WebSocket asked for on a path that serves none: 404 in the envelope, as an HTTP
    request there gets (a client reads 403 as a refusal of its token). Sent as the ASGI
    denial response where the server offers it, else the handshake is refused (403)."""
    path = scope["path"]
    message = f"no WebSocket at {path}: the live sockets are {' and '.join(live_paths)}"
    if (trimmed := path.rstrip("/")) in live_paths:
        message += f" (did you mean {trimmed}?)"
    if "websocket.http.response" not in scope.get("extensions", {}):
        await send({"type": "websocket.close", "code": 1008})
        return
    body = SafeJSONResponse(
        {"error": {"code": "not_found", "message": said(message), "details": None}}
    ).body
    headers = [(b"content-type", b"application/json"), (b"content-length", b"%d" % len(body))]
    await send({"type": "websocket.http.response.start", "status": 404, "headers": headers})
    await send({"type": "websocket.http.response.body", "body": body})
