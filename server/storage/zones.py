"""Operating areas and no-go zones: one document each, keyed by ``zone_id``, and the
set's version (``zones_meta``, ``_id: "version"``), raised with each change by a
compare-and-set so that every replica sees one order of changes.

A polygon is stored as rings of ``{lon, lat}`` points (FerretDB holds no arrays nested in
arrays), GeoJSON again when read.
"""

from __future__ import annotations

from typing import Any

from server.storage.backends import Doc, Duplicate, Store
from server.storage.obstacles import geojson_polygon, stored_polygon

#: Tries of the version's compare-and-set while other replicas change zones too.
_TRIES = 20


class ZonesRepo:
    def __init__(self, store: Store) -> None:
        self.zones = store["zones"]
        self.meta = store["zones_meta"]

    async def all(self) -> list[Doc]:
        docs = await self.zones.find({}, sort=[("created_version", 1), ("_id", 1)])
        return [_read(d) for d in docs]

    async def get(self, zone_id: str) -> Doc | None:
        doc = await self.zones.get(zone_id)
        return _read(doc) if doc is not None else None

    async def count(self) -> int:
        return await self.zones.count({})

    async def version(self) -> int:
        doc = await self.meta.get("version")
        return int(doc["version"]) if doc else 0

    async def next_version(self) -> int:
        """Raise the set's version by one; the new version."""
        for _ in range(_TRIES):
            current = await self.version()
            if current == 0:
                try:
                    await self.meta.insert({"_id": "version", "version": 1})
                    return 1
                except Duplicate:
                    continue
            if await self.meta.update(
                {"_id": "version", "version": current}, set={"version": current + 1}
            ):
                return current + 1
        raise RuntimeError("the zones' version keeps changing")

    async def insert(self, doc: Doc) -> None:
        await self.zones.insert(_stored(doc))

    async def replace(self, doc: Doc) -> bool:
        return await self.zones.replace({"_id": doc["zone_id"]}, _stored(doc))

    async def delete(self, zone_id: str) -> bool:
        return await self.zones.delete({"_id": zone_id}) > 0


def _stored(doc: Doc) -> dict[str, Any]:
    return {**doc, "_id": doc["zone_id"], "polygon": stored_polygon(doc["polygon"])}


def _read(doc: Doc) -> Doc:
    doc["polygon"] = geojson_polygon(doc["polygon"])
    doc.pop("_id", None)
    return doc
