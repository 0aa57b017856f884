"""Known fixed obstacles: admins draw and remove them, every user may see them."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from fleet_protocol import CreateObstacle, ObstacleList, ObstacleView, TimeBound
from server.api.deps import Admin, PathId, ServicesDep, Viewer
from server.errors import Invalid

router = APIRouter(tags=["admin"])


@router.post("/api/obstacles", status_code=201)
async def create_obstacle(body: CreateObstacle, admin: Admin, s: ServicesDep) -> ObstacleView:
    return ObstacleView.model_validate(await s.obstacles.create(body, admin))


@router.get("/api/obstacles")
async def list_obstacles(
    _: Viewer,
    s: ServicesDep,
    at: Annotated[
        TimeBound | None,
        Query(description="the obstacles there were then (**extension**; a replay's)"),
    ] = None,
    start: Annotated[
        TimeBound | None,
        Query(alias="from", description="with `to`: every obstacle there was in the window"),
    ] = None,
    end: Annotated[TimeBound | None, Query(alias="to")] = None,
) -> ObstacleList:
    """The obstacles there are; with ``at`` (**extension**), those there were then; with
    ``from`` and ``to``, every one there was at some time of the window, each removed one
    with its ``deleted_at`` (removed ones are kept for the retention)."""
    if at is not None and (start is not None or end is not None):
        raise Invalid(
            "give at, or from and to, not both",
            details=[{"field": "at", "message": "given with from or to"}],
        )
    if (start is None) != (end is None):
        missing = "to" if end is None else "from"
        raise Invalid(
            f"a window needs both from and to: {missing} is missing",
            details=[{"field": missing, "message": "missing: a window needs both"}],
        )
    if at is not None:
        docs = await s.obstacles.during(at, at)
    elif start is not None and end is not None:
        docs = await s.obstacles.during(start, end)
    else:
        docs = await s.obstacles.all()
    return ObstacleList(obstacles=[ObstacleView.model_validate(d) for d in docs])


@router.delete("/api/obstacles/{obstacle_id}")
async def delete_obstacle(obstacle_id: PathId, admin: Admin, s: ServicesDep) -> ObstacleView:
    return ObstacleView.model_validate(await s.obstacles.delete(obstacle_id, admin))
