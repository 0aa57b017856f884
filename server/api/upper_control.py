"""Vehicle side, commands: ``/upper/get_control`` (long poll) and ``/upper/update_fbmessage``."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from fleet_protocol import GetControlResult, UpdateFbMessage, UpdateFbMessageResult
from server.api.deps import ServicesDep, VehicleCaller
from server.api.responses import ModelResponse

router = APIRouter(prefix="/upper", tags=["vehicle"])


@router.get("/get_control", response_model=GetControlResult)
async def get_control(
    instance_id: Annotated[str, Query(min_length=1, max_length=64)],
    caller: VehicleCaller,
    s: ServicesDep,
    wait_s: Annotated[float, Query(ge=0, le=30, allow_inf_nan=False)] = 0,
) -> ModelResponse:
    commands = await s.commands.get_control(caller, instance_id, wait_s)
    return ModelResponse(
        GetControlResult.model_validate({"commands": [c.wire() for c in commands]})
    )


@router.post("/update_fbmessage")
async def update_fbmessage(
    body: UpdateFbMessage, caller: VehicleCaller, s: ServicesDep
) -> UpdateFbMessageResult:
    abort = await s.commands.acknowledge(caller, body.instance_id, body.control_mode, body.acks)
    return UpdateFbMessageResult(abort=abort)
