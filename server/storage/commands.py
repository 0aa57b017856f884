"""Commands: the active ones (small, replaced as they move) and the finished (insert-only).

A command lives in ``commands_active`` while it is not final, so that a
restarted server takes its queues up again. When it ends it is inserted
whole into ``commands`` first, under its own id (so the store takes each
command's end once, whichever replica records it), and only then deleted
from ``commands_active``: at every moment the store holds the command.
``commands`` only grows, trimmed by retention.
"""

from __future__ import annotations

from datetime import datetime

from server.storage.backends import Doc, Duplicate, Store


class CommandsRepo:
    def __init__(self, store: Store) -> None:
        self.store = store
        self.active = store["commands_active"]
        self.finished = store["commands"]

    async def ensure_indexes(self) -> None:
        await self.active.create_index([("instance_id", 1), ("seq", 1)])
        await self.finished.create_index([("instance_id", 1), ("issued_at", 1)])
        await self.finished.create_index([("ended_at", 1)])

    async def make_durable(self) -> None:
        """What was written so far survives a crash (the embedded store's journal)."""
        await self.store.make_durable()

    async def all_active(self) -> list[Doc]:
        return await self.active.find({}, sort=[("seq", 1)])

    async def active_for(self, instance_id: str) -> list[Doc]:
        return await self.active.find({"instance_id": instance_id}, sort=[("seq", 1)])

    async def active_for_many(self, instance_ids: list[str]) -> list[Doc]:
        return await self.active.find({"instance_id": {"$in": instance_ids}}, sort=[("seq", 1)])

    async def insert_active(self, docs: list[Doc]) -> None:
        await self.active.insert_many([{**doc, "_id": doc["command_id"]} for doc in docs])

    async def save_active(self, doc: Doc) -> bool:
        """Write a command that moved; False when it is no longer active (it ended)."""
        return await self.active.replace({"_id": doc["command_id"]}, dict(doc))

    async def finish(self, doc: Doc, ended_at: datetime) -> bool:
        """Record a command's end; False when it was recorded already (by another replica)."""
        try:
            await self.finished.insert({**doc, "_id": doc["command_id"], "ended_at": ended_at})
        except Duplicate:
            await self.active.delete({"_id": doc["command_id"]})
            return False
        await self.active.delete({"_id": doc["command_id"]})
        return True

    async def note_history(self, command_id: str, history: list[Doc]) -> None:
        """An ended command's history with a late ack written into it."""
        await self.finished.update({"_id": command_id}, set={"history": history})

    async def get(self, command_id: str) -> Doc | None:
        return await self.finished.get(command_id) or await self.active.get(command_id)

    async def recent_finished(self, instance_id: str, limit: int) -> list[Doc]:
        return await self.finished.find(
            {"instance_id": instance_id}, sort=[("issued_at", -1)], limit=limit
        )

    async def drop_finished_before(self, before: datetime) -> int:
        return await self.finished.delete({"ended_at": {"$lt": before}})
