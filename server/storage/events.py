"""The event log and audit trail: insert-only, with retention."""

from __future__ import annotations

from datetime import datetime
from typing import Any

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
    ) -> list[Doc]:
        flt: dict[str, Any] = {"at": {"$gte": start, "$lt": end}}
        if vehicle_ids is not None:
            flt["vehicle_id"] = vehicle_ids[0] if len(vehicle_ids) == 1 else {"$in": vehicle_ids}
        if kind:
            flt["kind"] = kind
        return await self.events.find(flt, sort=[("at", 1)], limit=limit, projection={"_id": 0})

    async def drop_before(self, before: datetime) -> int:
        return await self.events.delete({"at": {"$lt": before}})
