"""Commands: the active ones (small, replaced as they move) and the finished (insert-only).

A command lives in ``commands_active`` while it is not final, so that a
restarted server takes its queues up again; the moment it ends it is
deleted there and inserted whole into ``commands``, which only grows (and
is trimmed by retention).
"""

from __future__ import annotations

from datetime import datetime

from server.storage.driver import Doc, Store


class CommandsRepo:
    def __init__(self, store: Store) -> None:
        self.active = store["commands_active"]
        self.finished = store["commands"]

    async def ensure_indexes(self) -> None:
        await self.active.create_index([("command_id", 1)])
        await self.active.create_index([("instance_id", 1)])
        await self.finished.create_index([("command_id", 1)])
        await self.finished.create_index([("instance_id", 1), ("issued_at", -1)])
        await self.finished.create_index([("ended_at", 1)])

    async def all_active(self) -> list[Doc]:
        return await self.active.find({}, sort=[("seq", 1)], projection={"_id": 0})

    async def active_for(self, instance_id: str) -> list[Doc]:
        return await self.active.find(
            {"instance_id": instance_id}, sort=[("seq", 1)], projection={"_id": 0}
        )

    async def insert_active(self, docs: list[Doc]) -> None:
        await self.active.insert_many([dict(doc) for doc in docs])

    async def save_active(self, doc: Doc) -> None:
        await self.active.replace_one({"command_id": doc["command_id"]}, dict(doc))

    async def finish(self, doc: Doc, ended_at: datetime) -> None:
        await self.finished.insert_one({**doc, "ended_at": ended_at})
        await self.active.delete_many({"command_id": doc["command_id"]})

    async def claim_finish(self, doc: Doc, ended_at: datetime) -> bool:
        """Several replicas: the one that takes the command out of the active ones records
        its end (once); False if another already did."""
        if not await self.active.delete_many({"command_id": doc["command_id"]}):
            return False
        await self.finished.insert_one({**doc, "ended_at": ended_at})
        return True

    async def get(self, command_id: str) -> Doc | None:
        docs = await self.finished.find({"command_id": command_id}, projection={"_id": 0}, limit=1)
        if docs:
            return docs[0]
        docs = await self.active.find({"command_id": command_id}, projection={"_id": 0}, limit=1)
        return docs[0] if docs else None

    async def recent_finished(self, instance_id: str, limit: int) -> list[Doc]:
        return await self.finished.find(
            {"instance_id": instance_id},
            sort=[("issued_at", -1)],
            limit=limit,
            projection={"_id": 0},
        )

    async def drop_finished_before(self, before: datetime) -> int:
        return await self.finished.delete_many({"ended_at": {"$lt": before}})
