"""Records a background loop could not handle, kept aside with what they held.

Insert-only, with retention. ``raw`` is a text rendering of the record (it
could not be stored as it was), cut at :data:`MAX_RAW_CHARS`.
"""

from __future__ import annotations

from datetime import datetime

from server.storage.backends import Doc, Store

MAX_RAW_CHARS = 65_536


class DeadLettersRepo:
    def __init__(self, store: Store) -> None:
        self.coll = store["dead_letters"]

    async def ensure_indexes(self) -> None:
        await self.coll.create_index([("loop", 1), ("at", 1)])
        await self.coll.create_index([("at", 1)])

    async def insert(self, doc: Doc) -> None:
        await self.coll.insert(doc)

    async def of_loop(self, loop: str, limit: int = 100) -> list[Doc]:
        return await self.coll.find({"loop": loop}, sort=[("at", 1)], limit=limit)

    async def drop_before(self, before: datetime) -> int:
        return await self.coll.delete({"at": {"$lt": before}})
