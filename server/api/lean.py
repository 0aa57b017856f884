"""A route FastAPI declares, checks and documents, whose plain requests skip its machinery.

FastAPI's handler of a request (solving each dependency with its cache key and
scopes, two exit stacks, collecting parameters, then the endpoint) costs more
on this server than a vehicle's ``update_param`` itself (docs/benchmarks.md,
"Where the HTTP time goes"), and the vehicles' calls are the most frequent.
:class:`LeanRoute` keeps the route FastAPI's (the same path operation, the same
OpenAPI) and answers a *plain* request itself, the way FastAPI would:

- each query parameter validated by FastAPI's own field for it (its default
  when absent);
- the JSON body validated by the body model straight from the bytes (as the
  vehicle socket reads its frames), with ``Content-Type: application/json``;
- each dependency (a function of the request alone: the caller, the services)
  called as declared, in order, once: authorization is the same function on
  both paths;
- the endpoint called with them; it returns a finished :class:`Response`.

Anything else goes to FastAPI's handler of the route, with the body as it came:
a body that is not JSON or not valid, a query value that is not, a missing
content type, dependency overrides. So every error is FastAPI's own, in the
same order (a malformed JSON body is 422 before the token is looked at; a
valid one with a bad token is 401 before its fields are), and a valid request
gets the answer the endpoint gives either way. A route whose parameters are of
other kinds, whose endpoint returns a model, or that is reached through
``include_router`` (whose context builds its own handler) is FastAPI's alone.
FastAPI's own tracing spans of the dependencies and the endpoint (when
OpenTelemetry is set up) are not made on the lean path; the request's are.
"""

from __future__ import annotations

import inspect
import typing
from collections.abc import Awaitable, Callable, Mapping
from copy import deepcopy
from dataclasses import dataclass
from typing import Any

from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute
from pydantic import BaseModel, ValidationError
from starlette.requests import Request
from starlette.responses import Response
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from server.api.limits import replay

__all__ = ["LeanRoute"]

Dependency = Callable[[Request], Awaitable[Any]]


@dataclass(frozen=True, slots=True)
class _Query:
    name: str
    field: Any  # FastAPI's ModelField of the parameter: its own validation
    required: bool


@dataclass(frozen=True, slots=True)
class _Plan:
    """What a plain request of the route needs, read once from its FastAPI dependant."""

    endpoint: Callable[..., Awaitable[Response]]
    request_name: str | None
    query: tuple[_Query, ...]
    body: tuple[str, type[BaseModel]] | None
    dependencies: tuple[tuple[str, Dependency, bool], ...]  # name, call, use_cache


class LeanRoute(APIRoute):
    """An :class:`APIRoute` whose plain requests are answered without FastAPI's request
    handler (see the module). Declared like any route: ``APIRouter(route_class=LeanRoute)``."""

    def __init__(self, path: str, endpoint: Callable[..., Any], **kwargs: Any) -> None:
        super().__init__(path, endpoint, **kwargs)
        try:
            plan = _plan(self)
        except AttributeError:  # a FastAPI whose internals moved: its own handler serves
            plan = None
        if plan is not None:
            self.app = _LeanApp(plan, self.app, self.dependency_overrides_provider)


class _LeanApp:
    def __init__(self, plan: _Plan, standard: ASGIApp, overrides: Any) -> None:
        self.plan = plan
        self.standard = standard
        self.overrides = overrides

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        plan = self.plan
        if getattr(self.overrides, "dependency_overrides", None):
            await self.standard(scope, receive, send)
            return
        request = Request(scope, receive, send)
        values: dict[str, Any] = {}
        if plan.request_name is not None:
            values[plan.request_name] = request
        if plan.query and not _query_values(plan.query, request, values):
            await self.standard(scope, receive, send)
            return
        if plan.body is not None:
            messages, body = await _gather(receive)
            if body is None or not _body_value(plan.body, request, body, values):
                await self.standard(scope, replay(messages, receive), send)
                return
        called: dict[Dependency, Any] = {}
        for name, call, use_cache in plan.dependencies:
            if not use_cache or call not in called:
                called[call] = await call(request)
            values[name] = called[call]
        response = await plan.endpoint(**values)
        await response(scope, receive, send)


def _query_values(query: tuple[_Query, ...], request: Request, values: dict[str, Any]) -> bool:
    """Each query parameter's value, as FastAPI's field validates it; False: leave it to
    FastAPI (absent and required, empty, or not valid)."""
    undecoded = _undecoded_query(request.scope.get("query_string", b""))
    params: Mapping[str, str] = request.query_params if undecoded is None else undecoded
    for q in query:
        raw = params.get(q.name)
        if raw is None:
            if q.required:
                return False
            values[q.name] = deepcopy(q.field.default)
            continue
        if raw == "":
            return False
        value, errors = q.field.validate(raw, values, loc=("query", q.name))
        if errors:
            return False
        values[q.name] = value
    return True


def _undecoded_query(raw: bytes) -> dict[str, str] | None:
    """The query string's parameters when it has nothing to decode (ASCII, no ``%`` or
    ``+``), as Starlette reads them: pairs split on ``&``, a name alone has an empty
    value, the last of a repeated name counts (BodyLimit refuses one before any route).
    None otherwise: Starlette decodes it."""
    if b"%" in raw or b"+" in raw or not raw.isascii():
        return None
    params: dict[str, str] = {}
    for pair in raw.decode("ascii").split("&"):
        if pair:
            name, _, value = pair.partition("=")
            params[name] = value
    return params


def _body_value(
    body: tuple[str, type[BaseModel]], request: Request, raw: bytes, values: dict[str, Any]
) -> bool:
    """The body, validated by its model straight from JSON; False: leave it to FastAPI."""
    content_type = request.headers.get("content-type", "")
    if not raw or content_type.partition(";")[0].strip().lower() != "application/json":
        return False
    name, model = body
    try:
        values[name] = model.model_validate_json(raw)
    except ValidationError:
        return False
    return True


async def _gather(receive: Receive) -> tuple[list[Message], bytes | None]:
    """The request's messages to the end of its body, and the body (None: the client went)."""
    messages: list[Message] = []
    chunks: list[bytes] = []
    while True:
        message = await receive()
        messages.append(message)
        if message["type"] != "http.request":
            return messages, None
        chunks.append(message.get("body", b""))
        if not message.get("more_body", False):
            return messages, b"".join(chunks)


# ---- the plan, from the route's dependant -----------------------------------------------
def _plan(route: APIRoute) -> _Plan | None:
    """The plan of a route whose parameters are all of the kinds a plain request can
    fill; None for any other route (FastAPI serves it as usual)."""
    dependant = route.dependant
    endpoint = dependant.call
    if (
        endpoint is None
        or not inspect.iscoroutinefunction(endpoint)
        or not _returns_response(endpoint)
        or route.max_body_size is not None
        or dependant.path_params
        or dependant.header_params
        or dependant.cookie_params
        or _special(dependant)
    ):
        return None
    query = []
    for field in dependant.query_params:
        if not _plain_query(field):
            return None
        query.append(_Query(field.name, field, field.field_info.is_required()))
    body = None
    if dependant.body_params:
        body = _body_plan(route)
        if body is None:
            return None
    dependencies = []
    for sub in dependant.dependencies:
        if sub.name is None or sub.call is None or not _of_the_request_alone(sub):
            return None
        dependencies.append((sub.name, typing.cast(Dependency, sub.call), sub.use_cache))
    return _Plan(endpoint, dependant.request_param_name, tuple(query), body, tuple(dependencies))


def _returns_response(endpoint: Callable[..., Any]) -> bool:
    try:
        returned = typing.get_type_hints(endpoint).get("return")
    except (NameError, TypeError):
        return False
    return inspect.isclass(returned) and issubclass(returned, Response)


def _special(dependant: Dependant) -> bool:
    """Whether the dependant takes what a plain request does not give (a socket, the
    response to change, background tasks, security scopes)."""
    return bool(
        dependant.websocket_param_name
        or dependant.http_connection_param_name
        or dependant.response_param_name
        or dependant.background_tasks_param_name
        or dependant.security_scopes_param_name
        or dependant.own_oauth_scopes
        or dependant.parent_oauth_scopes
    )


def _plain_query(field: Any) -> bool:
    """A scalar query parameter read by its own name (no alias, no list, no model)."""
    info = field.field_info
    return (
        callable(getattr(field, "validate", None))
        and field.alias == field.name
        and info.validation_alias is None
        and info.annotation in (str, int, float, bool)
    )


def _body_plan(route: APIRoute) -> tuple[str, type[BaseModel]] | None:
    """One body parameter, the whole JSON body, of a model type."""
    params = route.dependant.body_params
    if len(params) != 1 or getattr(params[0].field_info, "embed", False):
        return None
    field = params[0]
    model = field.field_info.annotation
    if not (inspect.isclass(model) and issubclass(model, BaseModel)) or field.field_info.metadata:
        return None
    return field.name, model


def _of_the_request_alone(sub: Dependant) -> bool:
    """A dependency that is an ``async`` function of the request and nothing else."""
    return (
        inspect.iscoroutinefunction(sub.call)
        and sub.request_param_name is not None
        and not sub.dependencies
        and not sub.query_params
        and not sub.path_params
        and not sub.header_params
        and not sub.cookie_params
        and not sub.body_params
        and not _special(sub)
    )
