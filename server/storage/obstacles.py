"""Known fixed obstacles: one small document each, keyed by ``obstacle_id``.

A polygon is stored as rings of ``{lon, lat}`` points rather than GeoJSON's
arrays of arrays, which FerretDB does not hold; it is GeoJSON again when read.

A removed obstacle is kept in ``obstacles_removed`` (the same document and its
``deleted_at``) for the retention, so that a replay draws the obstacles there
were at its time (:meth:`ObstaclesRepo.during`). It is copied there before it
is deleted: a removal the store fails half-way leaves it in both, and the one
still in ``obstacles`` wins until the removal is made again.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from server.storage.backends import Doc, Store


def stored_polygon(polygon: dict[str, Any]) -> dict[str, Any]:
    rings = [
        {"points": [{"lon": p[0], "lat": p[1]} for p in ring]} for ring in polygon["coordinates"]
    ]
    return {"type": polygon["type"], "rings": rings}


def geojson_polygon(stored: dict[str, Any]) -> dict[str, Any]:
    if "coordinates" in stored:  # written by an earlier version
        return stored
    rings = [[[p["lon"], p["lat"]] for p in ring["points"]] for ring in stored["rings"]]
    return {"type": stored["type"], "coordinates": rings}


def _read(doc: Doc | None) -> Doc | None:
    if doc is not None:
        doc["polygon"] = geojson_polygon(doc["polygon"])
    return doc


class ObstaclesRepo:
    def __init__(self, store: Store) -> None:
        self.obstacles = store["obstacles"]
        self.removed = store["obstacles_removed"]

    async def all(self) -> list[Doc]:
        docs = await self.obstacles.find({}, sort=[("created_at", 1), ("_id", 1)])
        return [_read(d) or d for d in docs]

    async def get(self, obstacle_id: str) -> Doc | None:
        return _read(await self.obstacles.get(obstacle_id))

    async def count(self) -> int:
        return await self.obstacles.count({})

    async def insert(self, doc: Doc) -> None:
        stored = {**doc, "_id": doc["obstacle_id"], "polygon": stored_polygon(doc["polygon"])}
        await self.obstacles.insert(stored)

    async def delete(self, doc: Doc, at: datetime) -> bool:
        """Remove the obstacle ``doc`` (as read), kept aside as removed ``at``."""
        kept = {**doc, "_id": doc["obstacle_id"], "polygon": stored_polygon(doc["polygon"])}
        await self.removed.replace(
            {"_id": doc["obstacle_id"]}, {**kept, "deleted_at": at}, upsert=True
        )
        return await self.obstacles.delete({"_id": doc["obstacle_id"]}) > 0

    async def during(self, start: datetime, end: datetime) -> list[Doc]:
        """Every obstacle there was at some time from ``start`` to ``end`` (both included),
        oldest first; a removed one with its ``deleted_at``."""
        present = await self.obstacles.find({"created_at": {"$lte": end}})
        gone = await self.removed.find({"created_at": {"$lte": end}, "deleted_at": {"$gt": start}})
        here = {d["obstacle_id"] for d in present}
        docs = [_read(d) or d for d in present] + [
            _read(d) or d for d in gone if d["obstacle_id"] not in here
        ]
        docs.sort(key=lambda d: (d["created_at"], d["obstacle_id"]))
        return docs

    async def drop_removed_before(self, cutoff: datetime) -> int:
        """Retention: forget the obstacles removed before ``cutoff``."""
        return await self.removed.delete({"deleted_at": {"$lt": cutoff}})
