"""Operating areas and no-go zones: one document each, keyed by ``zone_id``, and the
set's version (``zones_meta``, ``_id: "version"``), raised with each change by a
compare-and-set so that every replica sees one order of changes.

Every change also keeps the zone as it became (``zone_versions``, ``_id``
``<zone_id>@<version>``, with ``at``, when, and ``deleted``): what the set was at a
past time is read from them (a replay draws the zones of its time). A zone's
first change since versions were kept records its shape before, from when it
last changed (``updated_at``), so that a zone drawn earlier has its past too.

A polygon is stored as rings of ``{lon, lat}`` points (FerretDB holds no arrays nested in
arrays), GeoJSON again when read.
"""

from __future__ import annotations

from collections.abc import Iterable
from datetime import datetime
from typing import Any

from server.storage.backends import Doc, Duplicate, Store
from server.storage.obstacles import geojson_polygon, stored_polygon

#: Tries of the version's compare-and-set while other replicas change zones too.
_TRIES = 20


class ZonesRepo:
    def __init__(self, store: Store) -> None:
        self.zones = store["zones"]
        self.meta = store["zones_meta"]
        self.versions = store["zone_versions"]

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

    async def ensure_indexes(self) -> None:
        await self.versions.create_index([("at", 1)])
        await self.versions.create_index([("zone_id", 1), ("version", 1)])

    async def add_version(self, doc: Doc, at: datetime, *, deleted: bool = False) -> None:
        """Keep ``doc`` as the zone became at ``at`` (once: a version kept already, by
        this replica or another, is left as it is)."""
        kept = {
            "_id": f"{doc['zone_id']}@{doc['version']}",
            "zone_id": doc["zone_id"],
            "version": doc["version"],
            "at": at,
            "deleted": deleted,
            "zone": _stored(doc),
        }
        try:
            await self.versions.insert(kept)
        except Duplicate:
            pass

    async def has_versions(self, zone_id: str) -> bool:
        return await self.versions.find_one({"zone_id": zone_id}) is not None

    async def versions_until(self, when: datetime) -> list[Doc]:
        """Every kept version from before ``when`` (included), in the set's order."""
        docs = await self.versions.find({"at": {"$lte": when}}, sort=[("version", 1)])
        return [_version(d) for d in docs]

    async def versions_between(self, start: datetime, end: datetime) -> list[Doc]:
        """The versions kept after ``start`` and up to ``end``, oldest first."""
        docs = await self.versions.find(
            {"at": {"$gt": start, "$lte": end}}, sort=[("at", 1), ("version", 1)]
        )
        return [_version(d) for d in docs]

    async def zones_with_versions(self, zone_ids: Iterable[str]) -> set[str]:
        wanted = list(zone_ids)
        if not wanted:
            return set()
        docs = await self.versions.find({"zone_id": {"$in": wanted}}, projection={"zone_id": 1})
        return {d["zone_id"] for d in docs}

    async def drop_versions_before(self, cutoff: datetime) -> int:
        """Retention: drop the versions that stopped being the zone's before ``cutoff``
        (a later version is from before it too), and every version of a zone deleted
        before it. What the set was at any time since ``cutoff`` can still be read."""
        old = await self.versions.find(
            {"at": {"$lt": cutoff}},
            sort=[("version", 1)],
            projection={"zone_id": 1, "version": 1, "deleted": 1},
        )
        last: dict[str, Doc] = {}
        for doc in old:
            last[doc["zone_id"]] = doc
        dropped = [d["_id"] for d in old if d is not last[d["zone_id"]] or bool(d.get("deleted"))]
        if not dropped:
            return 0
        return await self.versions.delete({"_id": {"$in": dropped}})


def _version(doc: Doc) -> Doc:
    doc["zone"] = _read(dict(doc["zone"]))
    return doc


def _stored(doc: Doc) -> dict[str, Any]:
    return {**doc, "_id": doc["zone_id"], "polygon": stored_polygon(doc["polygon"])}


def _read(doc: Doc) -> Doc:
    doc["polygon"] = geojson_polygon(doc["polygon"])
    doc.pop("_id", None)
    return doc
