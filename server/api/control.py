"""Operator side, arbitration: request, list, grant, revoke and release control."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from fleet_protocol import (
    ControlInfo,
    ControlRequest,
    ControlRequestList,
    DenyControl,
    GrantControl,
    InstanceRef,
    OkResult,
    OperatorHeartbeat,
    OperatorHeartbeatResult,
    RevokeResult,
)
from server.api.deps import Manager, Operator, ServicesDep, Viewer

router = APIRouter(prefix="/client", tags=["control"])


@router.post("/request_control")
async def request_control(body: InstanceRef, user: Operator, s: ServicesDep) -> ControlRequest:
    return ControlRequest.model_validate(await s.control_requests.request(user, body.instance_id))


@router.get("/control_requests")
async def control_requests(
    user: Viewer,
    s: ServicesDep,
    instance_id: Annotated[str | None, Query(min_length=1, max_length=64)] = None,
    mine: Annotated[
        bool,
        Query(description="the caller's own pending requests, not the ones it may answer"),
    ] = False,
) -> ControlRequestList:
    """The pending requests the caller may answer; with ``mine=true``, the caller's own
    (a console shows "Requested…" for them until they are answered or dropped)."""
    return ControlRequestList.model_validate(
        {"requests": await s.control_requests.pending(user, instance_id, mine=mine)}
    )


@router.post("/grant_control")
async def grant_control(body: GrantControl, user: Manager, s: ServicesDep) -> ControlInfo:
    lease = await s.control.grant(
        user, body.instance_id, body.user, body.duration_s, body.operator_timeout_s
    )
    return ControlInfo.model_validate(lease.info())


@router.post("/deny_control")
async def deny_control(body: DenyControl, user: Manager, s: ServicesDep) -> OkResult:
    """Decline a pending request for control (404 when there is none from that user);
    a ``control_deny`` event tells the requester, with the reason if given."""
    await s.control_requests.deny(user, body.instance_id, body.user, body.reason)
    return OkResult()


@router.post("/revoke_control")
async def revoke_control(body: InstanceRef, user: Manager, s: ServicesDep) -> RevokeResult:
    return RevokeResult(revoked=await s.control.revoke(user, body.instance_id))


@router.post("/release_control")
async def release_control(body: InstanceRef, user: Operator, s: ServicesDep) -> OkResult:
    await s.control.release(user, body.instance_id)
    return OkResult()


@router.post("/heartbeat")
async def operator_heartbeat(
    body: OperatorHeartbeat, user: Operator, s: ServicesDep
) -> OperatorHeartbeatResult:
    """The holder's client is alive. A lease granted with ``operator_timeout_s`` lapses
    (and the vehicle holds station) when none comes for that long; ``held`` lists the
    instances where the caller holds the lease."""
    return OperatorHeartbeatResult(held=await s.control.operator_heartbeat(user, body.instance_ids))
