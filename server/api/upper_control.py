"""Vehicle side, commands: ``/upper/get_control`` (long poll) and ``/upper/update_fbmessage``."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable
from typing import Annotated, Any, TypeVar

from fastapi import APIRouter, Query, Request

from fleet_protocol import GetControlResult, UpdateFbMessage, UpdateFbMessageResult
from server.api.deps import HubDep, ServicesDep, VehicleCaller
from server.api.lean import LeanRoute
from server.api.responses import ModelResponse
from server.domain.access import Principal
from server.errors import Unauthorized
from server.services.registry import Services

T = TypeVar("T")

# The vehicles' calls: the plain ones are answered without FastAPI's request handler.
router = APIRouter(prefix="/upper", tags=["vehicle"], route_class=LeanRoute)


async def _watched(
    s: Services, caller: Principal, request: Request, poll: Awaitable[T], wait_s: float
) -> T | None:
    """``poll``, unless the caller's token is revoked or expires first: then 401 at once
    (an open long poll must not hand out a command to a token that no longer stands);
    or unless the vehicle's connection closes first: then None, nothing handed out, and
    the poll no longer counts as contact (a vehicle that died in a long poll goes stale
    when its connection does, not when the poll would have ended). A poll that does not
    wait (``wait_s`` 0) is answered like any other call, under the token just checked:
    no watch (tasks and a turn of the event loop each call)."""
    if wait_s <= 0:
        return await poll
    waiting = asyncio.ensure_future(poll)
    revoked = asyncio.ensure_future(s.auth.until_invalid(caller))
    closed = asyncio.ensure_future(_until_closed(request))
    try:
        done, _ = await asyncio.wait(
            {waiting, revoked, closed}, return_when=asyncio.FIRST_COMPLETED
        )
    finally:
        revoked.cancel()
        closed.cancel()
    if waiting in done:
        return waiting.result()
    waiting.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await waiting
    if closed in done:
        return None
    raise Unauthorized("the token was revoked or expired during the long poll")


async def _until_closed(request: Request) -> None:
    """Returns once the client has closed its connection (the server reads nothing else
    from a GET)."""
    while (await request.receive())["type"] != "http.disconnect":
        pass


@router.get("/get_control", response_model=GetControlResult)
async def get_control(
    instance_id: Annotated[str, Query(min_length=1, max_length=64)],
    caller: VehicleCaller,
    s: ServicesDep,
    hub: HubDep,
    request: Request,
    wait_s: Annotated[float, Query(ge=0, le=30, allow_inf_nan=False)] = 0,
) -> ModelResponse:
    hub.calls_over_http(caller, instance_id)  # its commands come here now, not to a socket
    poll = s.link.get_control(caller, instance_id, wait_s)
    answered = await _watched(s, caller, request, poll, wait_s)
    if answered is None:  # nobody is there to read an answer
        return ModelResponse(GetControlResult(commands=[], abort=[]))
    commands, abort = answered
    result: dict[str, Any] = {
        "commands": [c.wire() for c in commands],
        "abort": abort,
        "control": s.control.lease_info(instance_id),
    }
    failsafe = await s.link.pending_failsafe(caller, instance_id)
    if failsafe is not None:  # a version the vehicle has not acknowledged yet
        result["failsafe"] = failsafe
    return ModelResponse(GetControlResult.model_validate(result))


@router.post("/update_fbmessage")
async def update_fbmessage(
    body: UpdateFbMessage, caller: VehicleCaller, s: ServicesDep
) -> UpdateFbMessageResult:
    abort = await s.link.feedback(caller, body)
    return UpdateFbMessageResult(abort=abort)
