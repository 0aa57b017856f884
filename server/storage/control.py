"""Control leases (one document per instance that has a lease) and pending requests."""

from __future__ import annotations

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

    async def drop_lease(self, instance_id: str) -> None:
        await self.leases.delete_many({"instance_id": instance_id})

    async def all_requests(self) -> list[Doc]:
        return await self.requests.find({}, sort=[("requested_at", 1)], projection={"_id": 0})

    async def insert_request(self, doc: Doc) -> None:
        await self.requests.insert_one(dict(doc))

    async def drop_requests(self, instance_id: str, username: str | None = None) -> None:
        flt: dict[str, str] = {"instance_id": instance_id}
        if username is not None:
            flt["username"] = username
        await self.requests.delete_many(flt)
