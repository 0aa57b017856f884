"""The control log: per vehicle, entries ``_id = "<vehicle_id>/<seq, 12 digits>"``.

The key makes each ``seq`` of a vehicle one entry at most: of two replicas appending at
once, the second finds the key taken, reads the new last entry and appends after it.
Nothing here updates or deletes an entry.
"""

from __future__ import annotations

from server.storage.backends import Doc, Duplicate, Store


class AuditRepo:
    def __init__(self, store: Store) -> None:
        self.entries = store["audit"]

    async def ensure_indexes(self) -> None:
        await self.entries.create_index([("vehicle_id", 1), ("seq", 1)], unique=True)

    async def last(self, vehicle_id: str) -> Doc | None:
        return await self.entries.find_one({"vehicle_id": vehicle_id}, sort=[("seq", -1)])

    async def append(self, doc: Doc) -> bool:
        """Whether this entry took its ``seq`` (False: another was appended first)."""
        try:
            await self.entries.insert({**doc, "_id": f"{doc['vehicle_id']}/{doc['seq']:012d}"})
        except Duplicate:
            return False
        return True

    async def page(self, vehicle_id: str, after_seq: int, limit: int) -> list[Doc]:
        return await self.entries.find(
            {"vehicle_id": vehicle_id, "seq": {"$gt": after_seq}}, sort=[("seq", 1)], limit=limit
        )
