"""The event log and audit trail: insert-only, with retention."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import Any

from bson import ObjectId

from server.storage.backends import Doc, Store


class EventsRepo:
    def __init__(self, store: Store) -> None:
        self.events = store["events"]

    async def ensure_indexes(self) -> None:
        await self.events.create_index([("vehicle_id", 1), ("at", 1)])
        await self.events.create_index([("at", 1)])

    async def insert(self, doc: Doc) -> None:
        await self.events.insert(doc)

    async def query(
        self,
        *,
        vehicle_ids: list[str] | None,
        kind: str | None,
        start: datetime,
        end: datetime,
        limit: int,
        after: tuple[datetime, str] | None = None,
    ) -> list[Doc]:
        """Events in ``(at, _id)`` order, each with its ``_id`` (an ObjectId: those one
        server inserts in one millisecond keep the order they came in); ``after``: only
        those past that pair (the ``_id`` as hex)."""
        flt: dict[str, Any] = {"at": {"$gte": start, "$lt": end}}
        if vehicle_ids is not None:
            flt["vehicle_id"] = vehicle_ids[0] if len(vehicle_ids) == 1 else {"$in": vehicle_ids}
        if kind:
            flt["kind"] = kind
        if after is not None:
            at, key = after
            flt["$or"] = [{"at": {"$gt": at}}, {"at": at, "_id": {"$gt": ObjectId(key)}}]
        return await self.events.find(flt, sort=[("at", 1), ("_id", 1)], limit=limit)

    async def latest(
        self, vehicle_id: str, count: int, *, besides: Sequence[str] = ()
    ) -> list[Doc]:
        """The vehicle's last ``count`` events, oldest first; with ``besides``, those of
        other kinds, and its stops (a ``command`` event of type ``stop``)."""
        flt: Doc = {"vehicle_id": vehicle_id}
        if besides:
            flt["$or"] = [
                {"kind": {"$nin": list(besides)}},
                {"kind": "command", "data.type": "stop"},
            ]
        docs = await self.events.find(
            flt,
            sort=[("at", -1), ("_id", -1)],
            limit=count,
            projection={"_id": 0},
        )
        return docs[::-1]

    async def drop_before(self, before: datetime) -> int:
        return await self.events.delete({"at": {"$lt": before}})
