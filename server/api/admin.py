"""Administration: vehicles, gateways, users, tokens; password login."""

from __future__ import annotations

import json
from typing import Annotated, Any
from urllib.parse import parse_qs

from fastapi import APIRouter, Depends, HTTPException, Query, Request
from fastapi.exceptions import RequestValidationError
from pydantic import ValidationError

from fleet_protocol import (
    CallerView,
    CreateGateway,
    CreateUser,
    CreateVehicle,
    DeadLetterList,
    GatewayCreated,
    GatewayList,
    GatewayView,
    LoginRequest,
    LogoutResult,
    PatchUser,
    PatchVehicle,
    TokenResult,
    UserCreated,
    UserList,
    UserView,
    VehicleCreated,
    VehicleView,
)
from server.api.deps import Admin, PathId, ServicesDep, Viewer
from server.errors import Invalid

router = APIRouter(tags=["admin"])


def _user_view(doc: dict[str, Any]) -> UserView:
    return UserView.model_validate(doc)


@router.post("/api/vehicles", status_code=201)
async def create_vehicle(body: CreateVehicle, _: Admin, s: ServicesDep) -> VehicleCreated:
    token = await s.auth.create_vehicle(body)
    return VehicleCreated(vehicle_id=body.vehicle_id, token=token)


@router.patch("/api/vehicles/{vehicle_id}")
async def patch_vehicle(
    vehicle_id: PathId, body: PatchVehicle, admin: Admin, s: ServicesDep
) -> VehicleView:
    """Change a vehicle's name or type (**extension**); the fleet's view of it after."""
    await s.instances.change_vehicle(admin, vehicle_id, body)
    return await s.views.vehicle(admin, vehicle_id)


@router.post("/api/vehicles/{vehicle_id}/rotate_token")
async def rotate_vehicle_token(vehicle_id: PathId, _: Admin, s: ServicesDep) -> VehicleCreated:
    return VehicleCreated(
        vehicle_id=vehicle_id, token=await s.auth.rotate_vehicle_token(vehicle_id)
    )


@router.post("/api/vehicles/{vehicle_id}/revoke_tokens")
async def revoke_vehicle_tokens(vehicle_id: PathId, _: Admin, s: ServicesDep) -> dict[str, bool]:
    await s.auth.revoke_vehicle_tokens(vehicle_id)
    return {"ok": True}


@router.post("/api/gateways", status_code=201)
async def create_gateway(body: CreateGateway, _: Admin, s: ServicesDep) -> GatewayCreated:
    token = await s.auth.create_gateway(body)
    return GatewayCreated(gateway_id=body.gateway_id, token=token, vehicles=body.vehicles)


@router.get("/api/gateways")
async def list_gateways(_: Admin, s: ServicesDep) -> GatewayList:
    """Every gateway: the vehicles it carries and how many of its tokens work now."""
    return GatewayList(
        gateways=[GatewayView.model_validate(d) for d in await s.auth.list_gateways()]
    )


@router.post("/api/gateways/{gateway_id}/rotate_token")
async def rotate_gateway_token(gateway_id: PathId, _: Admin, s: ServicesDep) -> GatewayCreated:
    token = await s.auth.rotate_gateway_token(gateway_id)
    gateway = await s.auth.get_gateway(gateway_id)
    return GatewayCreated(gateway_id=gateway_id, token=token, vehicles=gateway["vehicles"])


@router.post("/api/gateways/{gateway_id}/revoke_tokens")
async def revoke_gateway_tokens(gateway_id: PathId, _: Admin, s: ServicesDep) -> dict[str, bool]:
    await s.auth.revoke_gateway_tokens(gateway_id)
    return {"ok": True}


@router.post("/api/users", status_code=201)
async def create_user(body: CreateUser, _: Admin, s: ServicesDep) -> UserCreated:
    token = await s.auth.create_user(body)
    return UserCreated(username=body.username, role=body.role, token=token, vehicles=body.vehicles)


@router.get("/api/users")
async def list_users(_: Admin, s: ServicesDep) -> UserList:
    return UserList(users=[_user_view(d) for d in await s.auth.list_users()])


@router.get("/api/users/{username}")
async def get_user(username: PathId, _: Admin, s: ServicesDep) -> UserView:
    return _user_view(await s.auth.get_user(username))


@router.patch("/api/users/{username}")
async def patch_user(username: PathId, body: PatchUser, admin: Admin, s: ServicesDep) -> UserView:
    return _user_view(await s.auth.patch_user(username, body, admin))


@router.post("/api/users/{username}/rotate_token")
async def rotate_user_token(username: PathId, _: Admin, s: ServicesDep) -> UserCreated:
    user = await s.auth.get_user(username)
    token = await s.auth.rotate_user_token(username)
    return UserCreated(
        username=username, role=user["role"], token=token, vehicles=user.get("vehicles", [])
    )


@router.post("/api/users/{username}/revoke_tokens")
async def revoke_user_tokens(username: PathId, _: Admin, s: ServicesDep) -> dict[str, bool]:
    await s.auth.revoke_user_tokens(username)
    return {"ok": True}


@router.get("/api/dead_letters")
async def dead_letters(
    _: Admin,
    s: ServicesDep,
    loop: Annotated[str, Query(max_length=32)] = "telemetry",
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
) -> DeadLetterList:
    """What the background loops set aside (oldest first): the records they could not store
    or handle, with why."""
    return DeadLetterList.model_validate(
        {"dead_letters": await s.dead_letters.of_loop(loop, limit)}
    )


@router.get("/api/me", tags=["auth"])
async def me(user: Viewer) -> CallerView:
    """The user the token acts for: name, role, assigned vehicles, when the token ends."""
    return CallerView.model_validate(
        {
            "username": user.name,
            "role": user.role,
            "vehicles": sorted(user.vehicles),
            "expires_at": user.expires_at,
        }
    )


async def _login_body(request: Request) -> LoginRequest:
    """JSON as the contract says, or an OAuth2-style form (what many clients send)."""
    raw = await request.body()
    content_type = request.headers.get("content-type", "")
    if content_type.startswith("multipart/form-data"):
        raise Invalid(
            "send the login as JSON or as application/x-www-form-urlencoded",
            details=[{"field": "body", "message": "multipart/form-data is not read here"}],
        )
    try:
        if content_type.startswith("application/x-www-form-urlencoded"):
            form = {k: v[0] for k, v in parse_qs(raw.decode("utf-8", "replace")).items()}
            return LoginRequest.model_validate(form)
        try:  # read as every other route's body is (a byte-order mark, "\ud800" read)
            data = json.loads(raw)
        except (ValueError, RecursionError) as exc:  # answered as FastAPI's own refusal
            raise HTTPException(400, "There was an error parsing the body") from exc
        return LoginRequest.model_validate(data)
    except ValidationError as exc:
        raise RequestValidationError(exc.errors(), body=raw) from None


_LOGIN_SCHEMA = {
    "requestBody": {
        "required": True,
        "content": {
            "application/json": {"schema": LoginRequest.model_json_schema()},
            "application/x-www-form-urlencoded": {"schema": LoginRequest.model_json_schema()},
        },
    }
}


@router.post("/auth/logout", tags=["auth"])
async def log_out(caller: Viewer, s: ServicesDep) -> LogoutResult:
    """End the caller's session (**extension**): a token from ``/auth/token`` is revoked at
    once; an API token stays valid (the caller just stops using it)."""
    return LogoutResult(ended=await s.auth.log_out(caller))


@router.post(
    "/auth/token",
    tags=["auth"],
    openapi_extra=_LOGIN_SCHEMA,
    responses={429: {"description": "too many failed logins (Retry-After says when to retry)"}},
)
async def login(
    body: Annotated[LoginRequest, Depends(_login_body)], request: Request, s: ServicesDep
) -> TokenResult:
    """A session token for a username and password. Failed attempts are limited per client
    address and per username (``docs/security.md``)."""
    s.readiness.require()
    address = request.client.host if request.client is not None else None
    token, ttl = await s.auth.login(body.username, body.password, address)
    return TokenResult(access_token=token, expires_in=ttl)
