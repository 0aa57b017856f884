"""Operator side, commands: ``/client/submit_control``, ``get_fbmessage``, ``cancel_command``,
and ``/api/commands/{command_id}``."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Query

from fleet_protocol import (
    CancelCommand,
    CommandObject,
    GetFbMessageResult,
    SubmitControl,
    SubmitControlResult,
)
from server.api.deps import Operator, ServicesDep, Viewer

router = APIRouter(tags=["commands"])
InstanceId = Annotated[str, Query(min_length=1, max_length=64)]


@router.post("/client/submit_control", status_code=202)
async def submit_control(
    body: SubmitControl, user: Operator, s: ServicesDep
) -> SubmitControlResult:
    return SubmitControlResult.model_validate(await s.commands.submit(user, body))


@router.get("/client/get_fbmessage")
async def get_fbmessage(
    instance_id: InstanceId, user: Viewer, s: ServicesDep
) -> GetFbMessageResult:
    mode, commands = await s.commands.recent(user, instance_id)
    return GetFbMessageResult.model_validate(
        {"control_mode": mode, "commands": [c.wire() for c in commands]}
    )


@router.post("/client/cancel_command")
async def cancel_command(body: CancelCommand, user: Operator, s: ServicesDep) -> CommandObject:
    return CommandObject.model_validate((await s.commands.cancel(user, body.command_id)).wire())


@router.get("/api/commands/{command_id}")
async def get_command(
    command_id: Annotated[str, Path(max_length=64)], user: Viewer, s: ServicesDep
) -> CommandObject:
    return CommandObject.model_validate((await s.commands.get(user, command_id)).wire())
