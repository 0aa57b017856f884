"""The embedded store: mongomock-motor's in-process collections
(:mod:`server.storage.embedded_collection`), with a journal.

Writes are recorded in a journal (:mod:`server.storage.journal`) and durable once
:meth:`Store.flush` has written them to disk. On start the base snapshot and the
journal are read back into the collections; the journal is folded into a new base
of them at close, and while running whenever it outgrows the base.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from server.storage.base import ENCODE_ERRORS, Collection, Doc, Rejected, Store
from server.storage.embedded_collection import EmbeddedCollection
from server.storage.embedded_index import _aware
from server.storage.journal import Journal

log = logging.getLogger("fleet.storage")


#: The embedded store's journal is folded into its base once it is past this size and
#: twice the base's.
COMPACT_FLOOR_BYTES = 32 * 1024 * 1024


class EmbeddedStore(Store):
    """The collections of one process, their writes journaled to a file (see the module)."""

    kind = "embedded"
    durable_on_write = False

    def __init__(self, db_name: str, snapshot_path: Path) -> None:
        super().__init__()
        self.durability = f"journal fsynced by each flush ({snapshot_path})"
        import mongomock_motor

        self._client: Any = mongomock_motor.AsyncMongoMockClient(tz_aware=True)
        self._db = self._client[db_name]
        self.journal = Journal(snapshot_path)
        #: The journal is folded into the base once past this and twice the base.
        self.compact_floor_bytes = COMPACT_FLOOR_BYTES
        self._tables: dict[str, EmbeddedCollection] = {}
        self._loaded = False

    def _open(self, name: str) -> Collection:
        return self.collection(name)

    def collection(self, name: str) -> EmbeddedCollection:
        """The collection's table (what the journal records and replays)."""
        coll = self._tables.get(name)
        if coll is None:
            coll = self._tables[name] = EmbeddedCollection(self, self._db[name])
        return coll

    def encode(self, op: str, coll: str, **fields: Any) -> bytes:
        """A journal entry for a write about to be made; :class:`Rejected` when BSON
        cannot hold it, before anything is changed."""
        try:
            return self.journal.encode(op, coll, **fields)
        except ENCODE_ERRORS as exc:
            raise Rejected(f"{type(exc).__name__}: {exc}") from exc

    def record(self, entry: bytes | None) -> None:
        if entry is not None:
            self.journal.append(entry)

    async def ping(self) -> str | None:
        return None

    async def load(self) -> None:
        if self._loaded:
            return
        self._loaded = True
        counts = await self.journal.restore(self._replay, self._snapshot)
        if counts:
            log.info("embedded store restored from %s: %s", self.journal.path, counts)

    def _replay(self, entry: Mapping[str, Any]) -> None:
        coll = self.collection(entry["c"])
        op = entry["o"]
        if op == "insert":
            for doc in entry["d"]:
                if doc["_id"] not in coll._table:
                    coll.insert_now(_aware(doc), journal=False)
        elif op == "update":
            coll.update_now(entry["f"], entry["u"], upsert=entry.get("up", False), journal=False)
        elif op == "replace":
            coll.replace_now(
                entry["f"], entry["d"][0], upsert=entry.get("up", False), journal=False
            )
        elif op == "delete":
            coll.delete_now(entry["f"], journal=False)

    def _snapshot(self) -> Iterator[tuple[str, list[Doc]]]:
        for name in sorted(self._tables):
            yield name, self._tables[name].documents()

    async def flush(self) -> bool:
        flushed = await self.journal.flush()
        if self.journal.outgrown(self.compact_floor_bytes):
            # Folded in while running, not only at start and stop: the files stay near
            # the data's size however long the server runs (deletions make entries too).
            await self.journal.compact(self._snapshot)
        return flushed

    async def make_durable(self) -> bool:
        """The journal appended and fsynced (callers at the same moment share one)."""
        try:
            await self.journal.flush()
        except OSError as exc:
            log.error("writes answered before they are durable: the journal failed (%s)", exc)
            return False
        return True

    async def close(self) -> None:
        await self.journal.flush()
        await self.journal.compact(self._snapshot)
