"""Vehicle side, ``/upper/*`` (seed Table 1): instance life, heartbeat, telemetry."""

from __future__ import annotations

from fastapi import APIRouter

from fleet_protocol import (
    FinishInstance,
    FinishInstanceResult,
    Heartbeat,
    HeartbeatResult,
    StartInstance,
    StartInstanceResult,
    UpdateParamDocs,
    UpdateParamResult,
    WhoAmIResult,
)
from server.api.deps import HubDep, ServicesDep, VehicleCaller
from server.api.lean import LeanRoute
from server.api.responses import ModelResponse
from server.bus.wire import dumps

# The vehicles' calls: the plain ones are answered without FastAPI's request handler.
# A request is matched against the routes in order: the most frequent call is first.
router = APIRouter(prefix="/upper", tags=["vehicle"], route_class=LeanRoute)


@router.post("/update_param", response_model=UpdateParamResult)
async def update_param(
    body: UpdateParamDocs, caller: VehicleCaller, s: ServicesDep
) -> ModelResponse:
    """``UpdateParam``, its samples read as plain dicts: they are stored as they come."""
    # Most calls are done within this one (no coroutine of the link's to run).
    counts = s.link.update_param_now(caller, body, "http")
    if counts is None:
        counts = await s.link.update_param(caller, body, "http")
    return ModelResponse(dumps(counts))  # plain counters and the server's time, as text


@router.post("/start_instance")
async def start_instance(
    body: StartInstance, caller: VehicleCaller, s: ServicesDep, hub: HubDep
) -> StartInstanceResult:
    started = await s.link.start(caller, body)
    hub.calls_over_http(caller, started.instance_id, everywhere=True)  # a socket left half-open
    return started


@router.post("/finish_instance")
async def finish_instance(
    body: FinishInstance, caller: VehicleCaller, s: ServicesDep
) -> FinishInstanceResult:
    return await s.link.finish(caller, body.instance_id)


@router.post("/heartbeat")
async def heartbeat(body: Heartbeat, caller: VehicleCaller, s: ServicesDep) -> HeartbeatResult:
    return await s.link.heartbeat(caller, body.instance_id)


@router.get("/whoami")
async def whoami(caller: VehicleCaller, s: ServicesDep) -> WhoAmIResult:
    """Whom the token acts for (**extension**): a vehicle and itself, or a gateway and the
    vehicles it lists. The ``whoami`` op on ``/ws/vehicle`` answers the same."""
    return s.link.whoami(caller)
