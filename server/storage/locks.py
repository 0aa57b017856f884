"""Work that one replica does for all: a named lock held for a while and renewed.

``locks``: one document per name (``_id``), its ``holder`` and ``until``. A replica
takes a lock that is free or past its ``until``, or renews its own; the store's
conditional write decides between two replicas trying at once.
"""

from __future__ import annotations

from datetime import datetime

from server.storage.backends import Duplicate, Store


class LocksRepo:
    def __init__(self, store: Store) -> None:
        self.locks = store["locks"]

    async def hold(self, name: str, holder: str, now: datetime, until: datetime) -> bool:
        """Whether ``holder`` holds the lock ``name`` until ``until`` now."""
        if await self.locks.update({"_id": name, "holder": holder}, set={"until": until}):
            return True
        if await self.locks.update(
            {"_id": name, "until": {"$lt": now}}, set={"holder": holder, "until": until}
        ):
            return True
        try:
            await self.locks.insert({"_id": name, "holder": holder, "until": until})
        except Duplicate:
            return False
        return True
