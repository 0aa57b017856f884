"""Dependencies: the services, and who is calling. Every route names one caller alias.

Every route that needs a caller first requires the server to be ready (its
store reached at start-up): until then a 503 ``unavailable`` with
``Retry-After``.

Each caller alias is one ``async`` dependency on the request alone, not a chain
of them: FastAPI solves every dependency of a chain for itself on every request
(tens of microseconds each, a good part of a vehicle's call), and an ``async``
one runs on the event loop, never in the thread pool.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import Depends, Path, Request
from starlette.types import Scope

from server.api.live_hub import LiveHub
from server.domain.access import Principal
from server.errors import Forbidden
from server.services.registry import Services


async def get_services(request: Request) -> Services:
    services: Services = request.app.state.services
    return services


ServicesDep = Annotated[Services, Depends(get_services)]


async def get_hub(request: Request) -> LiveHub:
    hub: LiveHub = request.app.state.hub
    return hub


#: The live hub (sockets), for the HTTP routes that must tell it something.
HubDep = Annotated[LiveHub, Depends(get_hub)]


def bearer_token(scope: Scope) -> str | None:
    """The token of the request's ``Authorization: Bearer <token>`` header (its first
    ``Authorization``, as ``Headers`` reads it: ASGI names are lower case), read from the
    raw headers without building a ``Headers`` for each of the vehicles' calls."""
    header = next((v for k, v in scope["headers"] if k == b"authorization"), b"")
    scheme, _, value = header.decode("latin-1").partition(" ")
    if scheme.lower() == "bearer" and value.strip():
        return value.strip()
    return None


async def authenticate(request: Request) -> Principal:
    """Who calls: the server ready, the bearer token valid, within its rate."""
    services: Services = request.app.state.services
    services.readiness.require()
    token = bearer_token(request.scope)
    principal = services.auth.known(token) or await services.auth.authenticate(token)
    services.auth.check_rate(principal)
    return principal


async def get_principal(request: Request) -> Principal:
    """Any caller with a valid token."""
    return await authenticate(request)


def _require_user(role: str) -> Any:
    async def dependency(request: Request) -> Principal:
        principal = await authenticate(request)
        if principal.kind != "user":
            raise Forbidden("this call is for users, not vehicle or gateway tokens")
        if not principal.at_least(role):
            raise Forbidden(f"this call needs the {role} role or above")
        return principal

    return dependency


async def vehicle_caller(request: Request) -> Principal:
    """A vehicle's token, or a gateway's (which acts for the vehicles it lists)."""
    principal = await authenticate(request)
    if principal.kind not in ("vehicle", "gateway"):
        raise Forbidden("this call is for vehicle and gateway tokens")
    return principal


Viewer = Annotated[Principal, Depends(_require_user("viewer"))]
Operator = Annotated[Principal, Depends(_require_user("operator"))]
Manager = Annotated[Principal, Depends(_require_user("manager"))]
Admin = Annotated[Principal, Depends(_require_user("admin"))]
VehicleCaller = Annotated[Principal, Depends(vehicle_caller)]


#: An id in a path (a vehicle's, a user's, a zone's...): at most 64 characters, as every
#: id is; a longer one is a 422 naming it, not a 404 that writes it back whole.
PathId = Annotated[str, Path(min_length=1, max_length=64)]
