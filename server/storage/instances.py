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

    async def unfinished_for_vehicle(self, vehicle_id: str) -> Doc | None:
        return await self.latest_for_vehicle(vehicle_id, unfinished=True)

    async def contacts(self, instance_ids: list[str]) -> list[Doc]:
        """Last contact and position of these instances (several replicas)."""
        return await self.instances.find(
            {"_id": {"$in": instance_ids}},
            projection={"_id": 0, "instance_id": 1, "last_seen": 1, "position": 1},
        )

    async def claim_presence(self, instance_id: str, presence: str) -> bool:
        """Note a presence change once: whether this caller is the one that moved it.

        Several replicas may see the same vehicle go quiet; the one whose
        conditional write matches records the change.
        """
        flt = {"_id": instance_id, "presence": {"$ne": presence}}
        return await self.instances.update_one(flt, {"$set": {"presence": presence}}) > 0

    async def latest_for_vehicle(self, vehicle_id: str, *, unfinished: bool = False) -> Doc | None:
        query: dict[str, Any] = {"vehicle_id": vehicle_id}
        if unfinished:
            query["finished_at"] = None
        docs = await self.instances.find(
            query, sort=[("started_at", -1)], limit=1, projection={"_id": 0}
        )
        return docs[0] if docs else None

    async def insert(self, doc: Doc) -> None:
        # Keyed by the instance id, so a save is a keyed write (no scan on the embedded store).
        await self.instances.insert_one({**doc, "_id": doc["instance_id"]})

    async def save(self, instance_id: str, fields: dict[str, Any]) -> None:
        await self.instances.set_fields(instance_id, fields)

    async def save_shared(self, instance_id: str, fields: dict[str, Any]) -> None:
        """A write from one of several replicas: contact never moves back, and only
        :meth:`save` (``finish``) writes ``finished_at``."""
        seen = fields.get("last_seen")
        kept = {k: v for k, v in fields.items() if k not in ("finished_at", "last_seen")}
        update: dict[str, Any] = {"$set": kept}
        if seen is not None:
            update["$max"] = {"last_seen": seen}
        await self.instances.update_one({"_id": instance_id}, update)

    async def drop_finished_before(self, before: datetime) -> int:
        return await self.instances.delete_many({"finished_at": {"$lt": before}})
