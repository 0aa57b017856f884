"""Control leases (one document per instance that has a lease) and pending requests."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from server.storage.driver import Doc, Store


class ControlRepo:
    def __init__(self, store: Store) -> None:
        self.leases = store["control"]
        self.requests = store["control_requests"]

    async def ensure_indexes(self) -> None:
        await self.leases.create_index([("instance_id", 1)])
        await self.requests.create_index([("instance_id", 1)])

    async def all_leases(self) -> list[Doc]:
        return await self.leases.find({}, projection={"_id": 0})

    async def save_lease(self, doc: Doc) -> None:
        await self.leases.replace_one({"instance_id": doc["instance_id"]}, dict(doc), upsert=True)

    async def lease_of(self, instance_id: str) -> Doc | None:
        docs = await self.leases.find({"instance_id": instance_id}, projection={"_id": 0}, limit=1)
        return docs[0] if docs else None

    async def drop_lease(
        self, instance_id: str, *, holder: str | None = None, expired_by: datetime | None = None
    ) -> int:
        """Drop the instance's lease (only ``holder``'s, only if expired by then, when given);
        how many went: on several replicas, the one that drops it ends it."""
        flt: dict[str, Any] = {"instance_id": instance_id}
        if holder is not None:
            flt["holder"] = holder
        if expired_by is not None:
            flt["expires_at"] = {"$lte": expired_by}
        return await self.leases.delete_many(flt)

    async def all_requests(self) -> list[Doc]:
        return await self.requests.find({}, sort=[("requested_at", 1)], projection={"_id": 0})

    async def requests_of(self, instance_id: str | None) -> list[Doc]:
        flt = {"instance_id": instance_id} if instance_id is not None else {}
        return await self.requests.find(flt, sort=[("requested_at", 1)], projection={"_id": 0})

    async def insert_request(self, doc: Doc) -> None:
        await self.requests.insert_one(dict(doc))

    async def drop_requests(self, instance_id: str, username: str | None = None) -> None:
        flt: dict[str, str] = {"instance_id": instance_id}
        if username is not None:
            flt["username"] = username
        await self.requests.delete_many(flt)
