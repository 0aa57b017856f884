"""Known fixed obstacles: one small document each, keyed by ``obstacle_id``.

A polygon is stored as rings of ``{lon, lat}`` points rather than GeoJSON's
arrays of arrays, which FerretDB does not hold; it is GeoJSON again when read.
"""

from __future__ import annotations

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

    async def delete(self, obstacle_id: str) -> bool:
        return await self.obstacles.delete({"_id": obstacle_id}) > 0
