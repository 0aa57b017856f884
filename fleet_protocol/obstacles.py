"""Known fixed obstacles (land, piers, no-go zones) the path planner keeps clear of."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, StrictFloat, field_validator

from fleet_protocol.common import Latitude, Longitude, Timestamp, WireModel
from fleet_protocol.text import Label, Text

__all__ = [
    "MAX_OBSTACLE_VERTICES",
    "CreateObstacle",
    "ObstacleList",
    "ObstacleView",
    "PolygonGeometry",
]

#: Positions in one obstacle's polygon, all rings together.
MAX_OBSTACLE_VERTICES = 1000

#: A GeoJSON position: longitude first.
Position = tuple[Longitude, Latitude]


class PolygonGeometry(WireModel):
    """A GeoJSON Polygon geometry: the outer ring first, then any holes; each ring closed."""

    type: Literal["Polygon"]
    coordinates: list[list[Position]] = Field(min_length=1, max_length=MAX_OBSTACLE_VERTICES // 4)

    @field_validator("coordinates")
    @classmethod
    def _rings(cls, rings: list[list[Position]]) -> list[list[Position]]:
        total = sum(len(ring) for ring in rings)
        if total > MAX_OBSTACLE_VERTICES:
            raise ValueError(
                f"the polygon has {total} positions; at most {MAX_OBSTACLE_VERTICES} are accepted"
            )
        for index, ring in enumerate(rings):
            if len(ring) < 4:
                raise ValueError(
                    f"ring {index} has {len(ring)} positions; a ring needs at least 4 "
                    "(three corners and the first again)"
                )
            if ring[0] != ring[-1]:
                raise ValueError(
                    f"ring {index} is not closed: its last position must repeat its first"
                )
        return rings


class CreateObstacle(WireModel):
    name: Label = Field(min_length=1, max_length=128)
    polygon: PolygonGeometry
    clearance_m: StrictFloat | None = Field(
        default=None,
        ge=0,
        le=10_000,
        allow_inf_nan=False,
        description="how far a planned path keeps from it; unset: FLEET_SAFETY_RADIUS_M",
    )


class ObstacleView(WireModel):
    obstacle_id: Text
    name: Text
    polygon: PolygonGeometry
    clearance_m: float
    created_at: Timestamp
    #: When it was removed (**extension**: only in a list of a past time or window, which
    #: holds the obstacles removed since; null for one still there).
    deleted_at: Timestamp | None = None


class ObstacleList(WireModel):
    obstacles: list[ObstacleView]
