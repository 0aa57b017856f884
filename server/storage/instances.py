"""Instances (a vehicle's session with the server): hot state, small."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from server.storage.driver import Doc, Store


class InstancesRepo:
    def __init__(self, store: Store) -> None:
        self.instances = store["instances"]

    async def ensure_indexes(self) -> None:
        await self.instances.create_index([("instance_id", 1)])
        await self.instances.create_index([("vehicle_id", 1), ("finished_at", 1)])

    async def unfinished(self) -> list[Doc]:
        return await self.instances.find({"finished_at": None}, projection={"_id": 0})

    async def get(self, instance_id: str) -> Doc | None:
        doc = await self.instances.get(instance_id)
        if doc is not None:
            doc.pop("_id", None)
        return doc

    async def latest_for_vehicle(self, vehicle_id: str) -> Doc | None:
        docs = await self.instances.find(
            {"vehicle_id": vehicle_id}, sort=[("started_at", -1)], limit=1, projection={"_id": 0}
        )
        return docs[0] if docs else None

    async def insert(self, doc: Doc) -> None:
        # Keyed by the instance id, so a save is a keyed write (no scan on the embedded store).
        await self.instances.insert_one({**doc, "_id": doc["instance_id"]})

    async def save(self, instance_id: str, fields: dict[str, Any]) -> None:
        await self.instances.set_fields(instance_id, fields)

    async def drop_finished_before(self, before: datetime) -> int:
        return await self.instances.delete_many({"finished_at": {"$lt": before}})
