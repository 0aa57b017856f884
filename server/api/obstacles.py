"""Known fixed obstacles: admins draw and remove them, every user may see them."""

from __future__ import annotations

from fastapi import APIRouter

from fleet_protocol import CreateObstacle, ObstacleList, ObstacleView
from server.api.deps import Admin, PathId, ServicesDep, Viewer

router = APIRouter(tags=["admin"])


@router.post("/api/obstacles", status_code=201)
async def create_obstacle(body: CreateObstacle, admin: Admin, s: ServicesDep) -> ObstacleView:
    return ObstacleView.model_validate(await s.obstacles.create(body, admin))


@router.get("/api/obstacles")
async def list_obstacles(_: Viewer, s: ServicesDep) -> ObstacleList:
    return ObstacleList(obstacles=[ObstacleView.model_validate(d) for d in await s.obstacles.all()])


@router.delete("/api/obstacles/{obstacle_id}")
async def delete_obstacle(obstacle_id: PathId, admin: Admin, s: ServicesDep) -> ObstacleView:
    return ObstacleView.model_validate(await s.obstacles.delete(obstacle_id, admin))
