"""Control leases and pending control requests.

A lease's ``_id`` is its instance id: the store itself holds at most one per
instance. Every lease carries ``rev``, raised by each write; a write names
the ``rev`` it read, so of two replicas changing one lease at once the
second finds it changed and reads it again (compare and set). A request's
``_id`` is ``<instance_id>/<username>``: one per user and instance.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from server.storage.backends import Doc, Duplicate, Store


class ControlRepo:
    def __init__(self, store: Store) -> None:
        self.leases = store["control"]
        self.requests = store["control_requests"]

    async def ensure_indexes(self) -> None:
        await self.requests.create_index([("instance_id", 1), ("requested_at", 1)])
        await self.requests.create_index([("requested_at", 1)])

    async def all_leases(self) -> list[Doc]:
        return await self.leases.find({})

    async def lease_of(self, instance_id: str) -> Doc | None:
        return await self.leases.get(instance_id)

    async def leases_held_by(self, username: str) -> list[Doc]:
        """The leases this user holds (a scan: one lease per instance at most)."""
        return await self.leases.find({"holder": username})

    async def put_lease(self, doc: Doc, read_rev: int | None) -> bool:
        """Write the lease if it is still as read (``read_rev``; None: there was none)."""
        doc = {**doc, "_id": doc["instance_id"]}
        if read_rev is None:
            try:
                await self.leases.insert(doc)
            except Duplicate:
                return False
            return True
        return await self.leases.replace({"_id": doc["_id"], "rev": read_rev}, doc)

    async def operator_seen(self, instance_id: str, holder: str, at: datetime) -> bool:
        """The holder's client was heard at ``at`` (never moved back; the ``rev`` stays:
        a heartbeat changes no decision another replica is making)."""
        return await self.leases.update(
            {"_id": instance_id, "holder": holder}, max={"operator_seen_at": at}
        )

    async def drop_lease(self, instance_id: str, rev: int) -> bool:
        """Drop the lease if it is still the one read; whether this call dropped it."""
        return await self.leases.delete({"_id": instance_id, "rev": rev}) > 0

    async def all_requests(self) -> list[Doc]:
        return await self.requests.find({}, sort=[("requested_at", 1)])

    async def requests_of(self, instance_id: str) -> list[Doc]:
        return await self.requests.find({"instance_id": instance_id}, sort=[("requested_at", 1)])

    async def request_of(self, instance_id: str, username: str) -> Doc | None:
        return await self.requests.get(f"{instance_id}/{username}")

    async def insert_request(self, doc: Doc) -> bool:
        """False when the user has a request pending on the instance already."""
        try:
            await self.requests.insert({**doc, "_id": f"{doc['instance_id']}/{doc['username']}"})
        except Duplicate:
            return False
        return True

    async def drop_request(self, instance_id: str, username: str) -> bool:
        return await self.requests.delete({"_id": f"{instance_id}/{username}"}) > 0

    async def drop_requests(self, instance_id: str) -> None:
        await self.requests.delete({"instance_id": instance_id})

    async def requests_by(self, username: str) -> list[Doc]:
        """The requests this user has pending (a scan: bounded per instance)."""
        return await self.requests.find({"username": username})

    async def drop_requests_before(self, before: datetime) -> list[Doc]:
        old = await self.requests.find({"requested_at": {"$lt": before}})
        for doc in old:
            await self.requests.delete({"_id": doc["_id"]})
        return old

    @staticmethod
    def without_key(doc: Doc) -> dict[str, Any]:
        return {k: v for k, v in doc.items() if k != "_id"}
