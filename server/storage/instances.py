"""Instances (a vehicle's session with the server), and which one is each vehicle's.

An instance's ``_id`` is its instance id. ``vehicle_instances`` holds one
document per vehicle with an unfinished instance (``_id``: the vehicle id):
the store's own key makes it one per vehicle, however many replicas start
one at the same moment.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from server.storage.backends import Doc, Duplicate, Store


class InstancesRepo:
    def __init__(self, store: Store) -> None:
        self.instances = store["instances"]
        self.current = store["vehicle_instances"]

    async def ensure_indexes(self) -> None:
        await self.instances.create_index([("vehicle_id", 1), ("started_at", 1)])
        await self.instances.create_index([("finished_at", 1)])

    async def get(self, instance_id: str) -> Doc | None:
        return await self.instances.get(instance_id)

    async def get_many(self, instance_ids: list[str]) -> list[Doc]:
        return await self.instances.get_many(instance_ids)

    async def unfinished(self) -> list[Doc]:
        return await self.instances.find({"finished_at": None})

    async def latest_for_vehicle(self, vehicle_id: str) -> Doc | None:
        return await self.instances.find_one({"vehicle_id": vehicle_id}, sort=[("started_at", -1)])

    async def current_id(self, vehicle_id: str) -> str | None:
        """The vehicle's unfinished instance, as its claim says."""
        doc = await self.current.get(vehicle_id)
        return None if doc is None else str(doc["instance_id"])

    async def claim(self, vehicle_id: str, instance_id: str) -> bool:
        """Make ``instance_id`` the vehicle's one unfinished instance; False when another is."""
        try:
            await self.current.insert({"_id": vehicle_id, "instance_id": instance_id})
        except Duplicate:
            return False
        return True

    async def release(self, vehicle_id: str, instance_id: str) -> None:
        """The vehicle's claim, if it is still this instance's, ends."""
        await self.current.delete({"_id": vehicle_id, "instance_id": instance_id})

    async def insert(self, doc: Doc) -> None:
        await self.instances.insert({**doc, "_id": doc["instance_id"]})

    async def save(self, instance_id: str, fields: dict[str, Any]) -> None:
        """Write fields of the record; ``last_seen`` never moves back."""
        seen = fields.get("last_seen")
        rest = {k: v for k, v in fields.items() if k != "last_seen"}
        await self.instances.update(
            {"_id": instance_id}, set=rest, max={"last_seen": seen} if seen is not None else None
        )

    async def claim_presence(self, instance_id: str, presence: str) -> bool:
        """Note a presence change once: whether this caller is the one that moved it
        (of several replicas seeing a vehicle go quiet, the one whose write matched)."""
        return await self.instances.update(
            {"_id": instance_id, "presence": {"$ne": presence}}, set={"presence": presence}
        )

    async def drop_finished_before(self, before: datetime) -> int:
        return await self.instances.delete({"finished_at": {"$lt": before}})
