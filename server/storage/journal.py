"""Durability for the embedded store: a base snapshot plus a write-ahead journal.

mongomock keeps everything in memory. Every write the repositories make is
recorded here (BSON, in order) and appended to ``<snapshot>.journal`` on each
:meth:`Journal.flush`, fsynced. On start the base snapshot is loaded and the
journal replayed; then both are compacted into a new base snapshot. A flush
costs only what was written since the last one, so it can run every few
seconds even with a million samples stored.
"""

from __future__ import annotations

import asyncio
import logging
import os
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import bson

from server.storage import mock_table

log = logging.getLogger("fleet.storage")


def _entries(path: Path) -> Iterator[dict[str, Any]]:
    if not path.exists():
        return
    with path.open("rb") as fh:
        try:
            yield from bson.decode_file_iter(fh, bson.CodecOptions(tz_aware=True))
        except bson.errors.InvalidBSON:
            # A crash may leave a torn last entry: everything before it is kept.
            log.warning("journal %s ends in a torn entry; it is ignored", path)


class Journal:
    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.journal_path = self.path.with_name(self.path.name + ".journal")
        self._pending: list[bytes] = []
        self._lock = asyncio.Lock()
        self._collections: set[str] = set()

    def record(self, op: str, coll: str, **fields: Any) -> None:
        entry: dict[str, Any] = {"o": op, "c": coll}
        if "docs" in fields:
            entry["d"] = fields["docs"]
        if "flt" in fields:
            entry["f"] = dict(fields["flt"])
        if "update" in fields:
            entry["u"] = dict(fields["update"])
        if fields.get("upsert"):
            entry["up"] = True
        self._collections.add(coll)
        self._pending.append(bson.encode(entry))

    @property
    def pending(self) -> int:
        return len(self._pending)

    async def flush(self) -> bool:
        async with self._lock:
            if not self._pending:
                return False
            chunk, self._pending = self._pending, []
            await asyncio.to_thread(self._append, b"".join(chunk))
            return True

    def _append(self, data: bytes) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with self.journal_path.open("ab") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())

    async def restore(self, db: Any) -> dict[str, int]:
        """Load the base snapshot and replay the journal into ``db``; then compact."""
        counts: Counter[str] = Counter()
        for entry in _entries(self.path):
            coll = entry["c"]
            await db[coll].insert_many(entry["d"])
            counts[coll] += len(entry["d"])
        replayed = 0
        for entry in _entries(self.journal_path):
            await self._replay(db, entry)
            replayed += 1
        if counts or replayed:
            await self.compact(db)
        return dict(counts) | ({"journal_entries": replayed} if replayed else {})

    @staticmethod
    async def _replay(db: Any, entry: dict[str, Any]) -> None:
        coll = db[entry["c"]]
        op = entry["o"]
        flt = entry.get("f")
        if (
            op == "update"
            and flt is not None
            and list(flt) == ["_id"]
            and list(entry["u"]) == ["$set"]
        ):
            table = mock_table.table_of(coll)  # keyed: no scan (thousands per restart)
            if table is not None and mock_table.set_fields(table, flt["_id"], entry["u"]["$set"]):
                return
        if op == "insert":
            await coll.insert_many(entry["d"])
        elif op == "update":
            await coll.update_one(entry["f"], entry["u"], upsert=entry.get("up", False))
        elif op == "replace":
            await coll.replace_one(entry["f"], entry["d"][0], upsert=entry.get("up", False))
        elif op == "delete":
            await coll.delete_many(entry["f"])

    async def compact(self, db: Any) -> None:
        """Write every collection into a new base snapshot and empty the journal."""
        async with self._lock:
            names = sorted(set(await db.list_collection_names()) | self._collections)
            chunks: list[bytes] = []
            for name in names:
                docs = await db[name].find({}).to_list(None)
                for i in range(0, len(docs), 500):
                    chunks.append(bson.encode({"c": name, "d": docs[i : i + 500]}))
            self._pending.clear()
            await asyncio.to_thread(self._write_base, chunks)

    def _write_base(self, chunks: list[bytes]) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_name(self.path.name + ".tmp")
        with tmp.open("wb") as fh:
            for chunk in chunks:
                fh.write(chunk)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, self.path)
        # The base now holds everything the journal said.
        with self.journal_path.open("wb") as fh:
            fh.flush()
            os.fsync(fh.fileno())

    async def close(self) -> None:
        await self.flush()
