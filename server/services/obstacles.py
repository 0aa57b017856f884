"""Known fixed obstacles: an admin draws them, the planner keeps clear of them.

Read from the store on each planned path, so every replica plans round the
same set at once; there are few (``FLEET_MAX_OBSTACLES``), each small.
"""

from __future__ import annotations

import itertools
import secrets
from datetime import datetime
from typing import Any

import shapely
from shapely.validation import explain_validity

from fleet_protocol import CreateObstacle, PolygonGeometry
from server.domain.clock import Clock
from server.domain.plan_frame import Zone
from server.errors import Conflict, Invalid, NotFound
from server.services.events import EventService
from server.settings import Settings
from server.storage.backends import Doc
from server.storage.obstacles import ObstaclesRepo


def check_polygon(polygon: PolygonGeometry) -> None:
    """A polygon the planner can work with: valid as a whole (no self-intersection,
    holes inside the outer ring), not only ring by ring as the wire model checks."""
    shell, *holes = polygon.coordinates
    for r, ring in enumerate(polygon.coordinates):
        for i, (a, b) in enumerate(itertools.pairwise(ring)):
            if abs(b[0] - a[0]) > 180:  # GeoJSON draws it the long way round the globe
                where = f"polygon.coordinates.{r}.{i + 1}"
                raise Invalid(
                    "an edge spans more than 180 degrees of longitude: a polygon across "
                    "the antimeridian is drawn as two, split at 180 (RFC 7946)",
                    details=[{"field": where, "message": "more than 180 degrees from the last"}],
                )
    try:
        reason = explain_validity(shapely.Polygon(shell, holes))
    except (ValueError, shapely.errors.GEOSException) as exc:
        reason = str(exc)
    if reason != "Valid Geometry":
        raise Invalid(
            f"the polygon is not valid: {reason}",
            details=[{"field": "polygon.coordinates", "message": reason}],
        )


def zone_of(doc: Doc) -> Zone:
    rings = tuple(
        tuple((float(lat), float(lon)) for lon, lat in ring)
        for ring in doc["polygon"]["coordinates"]
    )
    return Zone(rings, float(doc["clearance_m"]), doc["name"])


class ObstacleService:
    def __init__(
        self, settings: Settings, repo: ObstaclesRepo, events: EventService, clock: Clock
    ) -> None:
        self.settings = settings
        self.repo = repo
        self.events = events
        self.clock = clock

    async def _changed(self, doc: Doc, action: str, actor: Any) -> None:
        """Recorded (``obstacles_changed``, the fleet's), and so told on the ``zones``
        topic: a console open draws the obstacles again."""
        data = {"obstacle_id": doc["obstacle_id"], "name": doc["name"], "action": action}
        await self.events.record("obstacles_changed", actor=actor, data=data)

    async def create(self, body: CreateObstacle, actor: Any = None) -> Doc:
        check_polygon(body.polygon)
        if await self.repo.count() >= self.settings.max_obstacles:
            raise Conflict(
                f"there are already {self.settings.max_obstacles} obstacles "
                "(FLEET_MAX_OBSTACLES); delete one first"
            )
        clearance = body.clearance_m
        doc: dict[str, Any] = {
            "obstacle_id": "o-" + secrets.token_hex(8),
            "name": body.name,
            "polygon": body.polygon.model_dump(mode="json"),
            "clearance_m": self.settings.safety_radius_m if clearance is None else clearance,
            "created_at": self.clock(),
        }
        await self.repo.insert(doc)
        await self._changed(doc, "created", actor)
        return doc

    async def all(self) -> list[Doc]:
        return await self.repo.all()

    async def delete(self, obstacle_id: str, actor: Any = None) -> Doc:
        doc = await self.repo.get(obstacle_id)
        if doc is None or not await self.repo.delete(doc, self.clock()):
            raise NotFound(f"no obstacle {obstacle_id}")
        await self._changed(doc, "deleted", actor)
        return doc

    async def during(self, start: datetime, end: datetime) -> list[Doc]:
        """The obstacles there were at some time of the window (a replay's): those still
        there and those removed since ``start`` (kept for the retention)."""
        if end < start:
            raise Invalid(
                "to is before from",
                details=[{"field": "to", "message": "before from"}],
            )
        return await self.repo.during(start, end)

    async def zones(self) -> list[Zone]:
        """What the planner keeps clear of."""
        return [zone_of(doc) for doc in await self.repo.all()]
