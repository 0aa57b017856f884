"""Operating areas and no-go zones: admins draw, change and remove them; every user sees
those that concern the vehicles they see (a zone for every vehicle concerns everyone)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from fleet_protocol import (
    CreateZone,
    PatchZone,
    TimeBound,
    ZoneChange,
    ZoneChanges,
    ZoneList,
    ZoneView,
)
from server.api.deps import Admin, PathId, ServicesDep, Viewer
from server.domain.access import Principal, zone_vehicles_seen
from server.errors import NotFound
from server.storage.backends import Doc

router = APIRouter(tags=["zones"])


def _seen(doc: Doc, user: Principal) -> ZoneView | None:
    """The zone as this user sees it (``zone_vehicles_seen``): only the vehicles they
    see, or not at all when it concerns none of them."""
    visible = zone_vehicles_seen(doc.get("vehicles") or [], user)
    return None if visible is None else ZoneView.model_validate({**doc, "vehicles": visible})


@router.get("/api/zones")
async def list_zones(
    user: Viewer,
    s: ServicesDep,
    at: Annotated[
        TimeBound | None,
        Query(description="the zones as they were then (**extension**; a replay's)"),
    ] = None,
) -> ZoneList:
    docs, version = await s.zones.all() if at is None else await s.zones.at(at)
    views = [v for d in docs if (v := _seen(d, user)) is not None]
    return ZoneList(zones=views, version=version)


@router.get("/api/zones/changes")
async def zone_changes(
    user: Viewer,
    s: ServicesDep,
    start: Annotated[TimeBound, Query(alias="from")],
    end: Annotated[TimeBound, Query(alias="to")],
) -> ZoneChanges:
    """(**extension**) The changes of the zones the caller sees, after ``from`` and up to
    ``to``: what a replay reads the set again after (``?at=``)."""
    kept = await s.zones.changes(start, end)
    return ZoneChanges(
        changes=[
            ZoneChange(at=k["at"], version=k["version"], zone_id=k["zone_id"], deleted=k["deleted"])
            for k in kept
            if _seen(k["zone"], user) is not None
        ]
    )


@router.get("/api/zones/{zone_id}")
async def get_zone(zone_id: PathId, user: Viewer, s: ServicesDep) -> ZoneView:
    view = _seen(await s.zones.get(zone_id), user)
    if view is None:
        raise NotFound(f"no zone {zone_id}")  # as an unknown one (docs/security.md)
    return view


@router.post("/api/zones", status_code=201)
async def create_zone(body: CreateZone, admin: Admin, s: ServicesDep) -> ZoneView:
    return ZoneView.model_validate(await s.zones.create(body, admin))


@router.patch("/api/zones/{zone_id}")
async def patch_zone(zone_id: PathId, body: PatchZone, admin: Admin, s: ServicesDep) -> ZoneView:
    return ZoneView.model_validate(await s.zones.patch(zone_id, body, admin))


@router.delete("/api/zones/{zone_id}")
async def delete_zone(zone_id: PathId, admin: Admin, s: ServicesDep) -> ZoneView:
    return ZoneView.model_validate(await s.zones.delete(zone_id, admin))
