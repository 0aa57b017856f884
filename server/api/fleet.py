"""Fleet views for operators: vehicles, instances, parameters, events."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from fleet_protocol import (
    ConnectInstance,
    ConnectInstanceResult,
    EventKind,
    EventList,
    GetParamResult,
    TimeBound,
    VehicleList,
    VehicleView,
)
from server.api.deps import PathId, ServicesDep, Viewer

router = APIRouter(tags=["fleet"])
InstanceId = Annotated[str, Query(min_length=1, max_length=64)]


@router.get("/api/vehicles")
async def list_vehicles(user: Viewer, s: ServicesDep) -> VehicleList:
    return VehicleList(vehicles=await s.views.vehicles(user))


@router.get("/api/vehicles/{vehicle_id}")
async def get_vehicle(vehicle_id: PathId, user: Viewer, s: ServicesDep) -> VehicleView:
    return await s.views.vehicle(user, vehicle_id)


@router.post("/client/connect_instance")
async def connect_instance(
    body: ConnectInstance, user: Viewer, s: ServicesDep
) -> ConnectInstanceResult:
    return ConnectInstanceResult(instance=await s.views.connect(user, body))


@router.get("/client/get_param")
async def get_param(
    instance_id: InstanceId,
    user: Viewer,
    s: ServicesDep,
    names: Annotated[str | None, Query(max_length=4096)] = None,
) -> GetParamResult:
    wanted = [n.strip() for n in names.split(",") if n.strip()] if names else None
    return await s.views.params(user, instance_id, wanted)


@router.get("/api/events")
async def list_events(
    user: Viewer,
    s: ServicesDep,
    vehicle_id: Annotated[str | None, Query(max_length=64)] = None,
    kind: EventKind | None = None,
    start: Annotated[TimeBound | None, Query(alias="from")] = None,
    end: Annotated[TimeBound | None, Query(alias="to")] = None,
    limit: Annotated[int, Query(ge=1, le=10_000)] = 1000,
    after: Annotated[str | None, Query(max_length=128)] = None,
) -> EventList:
    if vehicle_id is not None:
        await s.views.visible_vehicle(user, vehicle_id)
    page = await s.events.query(
        user, vehicle_id=vehicle_id, kind=kind, start=start, end=end, limit=limit, after=after
    )
    return EventList.model_validate(page)
