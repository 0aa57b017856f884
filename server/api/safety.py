"""A vehicle's failsafe (everyone who sees the vehicle reads it; an admin or the
vehicle's field manager sets it) and its control log."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from fleet_protocol import AuditPage, FailsafeView, SetFailsafe
from server.api.deps import Manager, PathId, ServicesDep, Viewer
from server.api.fleet_telemetry import VisibleVehicle
from server.services.audit import MAX_PAGE

router = APIRouter(tags=["fleet"])


@router.get("/api/vehicles/{vehicle_id}/failsafe")
async def get_failsafe(vehicle_id: PathId, user: Viewer, s: ServicesDep) -> FailsafeView:
    return FailsafeView.model_validate(await s.safety.view(user, vehicle_id))


@router.put("/api/vehicles/{vehicle_id}/failsafe")
async def set_failsafe(
    vehicle_id: PathId, body: SetFailsafe, user: Manager, s: ServicesDep
) -> FailsafeView:
    """The whole policy: ``none``, ``keep_station``, ``stop`` or ``return_home`` after
    ``after_s`` without the server (``home``: the instance's first position unless set);
    ``on_breach``: the same action when the vehicle enters a no-go zone or leaves its
    operating area; ``low_battery_pct``: a ``low_battery`` event below it. The vehicle
    gets it at once (a ``failsafe`` push, or with its next ``get_control``) and
    acknowledges the version it applies."""
    return FailsafeView.model_validate(await s.safety.set_policy(user, vehicle_id, body))


@router.get("/api/vehicles/{vehicle_id}/audit")
async def audit(
    vehicle_id: VisibleVehicle,
    s: ServicesDep,
    after_seq: Annotated[int, Query(ge=0, le=2**62)] = 0,
    limit: Annotated[int, Query(ge=1, le=MAX_PAGE)] = MAX_PAGE,
) -> AuditPage:
    """The vehicle's control log, oldest first: grants, leases, commands, failsafes, each
    entry with the hash of the one before (``fleetctl audit verify`` checks the chain).
    ``next_after_seq``: pass it as ``after_seq`` for the next page (null: no more)."""
    entries, more = await s.audit.page(vehicle_id, after_seq, limit)
    return AuditPage.model_validate({"entries": entries, "next_after_seq": more})
