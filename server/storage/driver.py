"""One async interface over the two drivers.

Real: PyMongo's ``AsyncMongoClient`` (``FLEET_MONGO_URL`` set). Embedded:
mongomock-motor in process, made durable by :mod:`server.storage.journal`.
Every difference between the two (``aggregate`` awaited or not, error
types, durability of a write) is absorbed here and nowhere else.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any

from pymongo.errors import ConnectionFailure, DuplicateKeyError, OperationFailure, PyMongoError

from server.errors import Unavailable
from server.settings import Settings
from server.storage import mock_table
from server.storage.journal import Journal

log = logging.getLogger("fleet.storage")

Doc = dict[str, Any]


class Collection:
    """A collection of either driver, with the few call shapes the repositories use."""

    def __init__(self, raw: Any, store: Store) -> None:
        self._raw = raw
        self._store = store
        self.name: str = raw.name
        #: The embedded store's table (``_id`` -> document), for keyed writes.
        self.table: Any | None = mock_table.table_of(raw) if store.embedded else None

    async def get(self, _id: Any) -> Doc | None:
        """The document with this ``_id``: no scan on the embedded store."""
        if self.table is None:
            return await self.find_one({"_id": _id})
        return mock_table.read(self.table, _id)

    async def set_fields(self, _id: Any, fields: Mapping[str, Any]) -> bool:
        """``$set`` on the document with this ``_id``: no scan on the embedded store."""
        if self.table is None:
            return await self.update_one({"_id": _id}, {"$set": dict(fields)}) > 0
        if not mock_table.set_fields(self.table, _id, dict(fields)):
            return False
        self._store.journal_op("update", self.name, flt={"_id": _id}, update={"$set": fields})
        return True

    async def insert_one(self, doc: Doc) -> None:
        async with self._store.guard():
            await self._raw.insert_one(doc)
        self._store.journal_op("insert", self.name, docs=[doc])

    async def append(self, doc: Doc) -> None:
        """``insert_one`` into a collection that has no unique index (time series):
        straight into the embedded store's table, without a scan or a trial encoding."""
        if self.table is None:
            await self.insert_one(doc)
            return
        if not mock_table.insert(self.table, doc):
            raise DuplicateKeyError(f"E11000 duplicate key: {doc['_id']!r}")
        self._store.journal_op("insert", self.name, docs=[doc])

    async def insert_many(self, docs: Sequence[Doc]) -> None:
        if not docs:
            return
        async with self._store.guard():
            await self._raw.insert_many(list(docs), ordered=True)
        self._store.journal_op("insert", self.name, docs=list(docs))

    async def find(
        self,
        flt: Mapping[str, Any] | None = None,
        *,
        sort: list[tuple[str, int]] | None = None,
        limit: int = 0,
        projection: Mapping[str, Any] | None = None,
    ) -> list[Doc]:
        async with self._store.guard():
            cursor = self._raw.find(dict(flt or {}), projection)
            if sort:
                cursor = cursor.sort(sort)
            if limit:
                cursor = cursor.limit(limit)
            docs: list[Doc] = await cursor.to_list(None)
        return docs

    async def find_one(
        self, flt: Mapping[str, Any], *, sort: list[tuple[str, int]] | None = None
    ) -> Doc | None:
        docs = await self.find(flt, sort=sort, limit=1)
        return docs[0] if docs else None

    async def update_one(
        self, flt: Mapping[str, Any], update: Mapping[str, Any], *, upsert: bool = False
    ) -> int:
        async with self._store.guard():
            result = await self._raw.update_one(dict(flt), dict(update), upsert=upsert)
        self._store.journal_op("update", self.name, flt=flt, update=update, upsert=upsert)
        return int(result.matched_count) + (1 if result.upserted_id is not None else 0)

    async def replace_one(self, flt: Mapping[str, Any], doc: Doc, *, upsert: bool = False) -> int:
        async with self._store.guard():
            result = await self._raw.replace_one(dict(flt), doc, upsert=upsert)
        self._store.journal_op("replace", self.name, flt=flt, docs=[doc], upsert=upsert)
        return int(result.matched_count) + (1 if result.upserted_id is not None else 0)

    async def delete_many(self, flt: Mapping[str, Any]) -> int:
        async with self._store.guard():
            result = await self._raw.delete_many(dict(flt))
        if result.deleted_count:
            self._store.journal_op("delete", self.name, flt=flt)
        return int(result.deleted_count)

    async def count(self, flt: Mapping[str, Any] | None = None) -> int:
        async with self._store.guard():
            n = await self._raw.count_documents(dict(flt or {}))
        return int(n)

    async def aggregate(self, pipeline: list[Mapping[str, Any]]) -> list[Doc]:
        async with self._store.guard():
            cursor = self._raw.aggregate(pipeline)
            if not self._store.embedded:
                cursor = await cursor  # PyMongo async: aggregate is a coroutine
            docs: list[Doc] = await cursor.to_list(None)
        return docs

    async def create_index(self, keys: list[tuple[str, int]], **kwargs: Any) -> None:
        async with self._store.guard():
            await self._raw.create_index(keys, **kwargs)


class _Guard:
    """Turns driver failures into the contract's 503 ``unavailable``."""

    async def __aenter__(self) -> None:
        return None

    async def __aexit__(self, exc_type: Any, exc: BaseException | None, tb: Any) -> bool:
        if exc is None:
            return False
        if isinstance(exc, ConnectionFailure):
            raise Unavailable("the store cannot be reached; try again shortly") from exc
        if isinstance(exc, OperationFailure):
            return False
        if isinstance(exc, PyMongoError):
            raise Unavailable(f"the store failed: {type(exc).__name__}") from exc
        return False


class Store:
    def __init__(self, settings: Settings, raw_client: Any, *, embedded: bool) -> None:
        self.settings = settings
        self.embedded = embedded
        self._client = raw_client
        self._db = raw_client[settings.db_name]
        self._collections: dict[str, Collection] = {}
        self._guard = _Guard()
        self.journal: Journal | None = None

    def guard(self) -> _Guard:
        return self._guard

    def __getitem__(self, name: str) -> Collection:
        coll = self._collections.get(name)
        if coll is None:
            coll = self._collections[name] = Collection(self._db[name], self)
        return coll

    def journal_op(self, op: str, coll: str, **fields: Any) -> None:
        if self.journal is not None:
            self.journal.record(op, coll, **fields)

    @property
    def durable_on_write(self) -> bool:
        """A real MongoDB acknowledges journaled writes; the embedded store after a flush."""
        return not self.embedded

    async def flush(self) -> bool:
        """Make every write so far durable. Returns whether anything was written."""
        if self.journal is None:
            return False
        return await self.journal.flush()

    async def ping(self) -> bool:
        if self.embedded:
            return True
        try:
            await self._client.admin.command("ping")
        except PyMongoError:
            return False
        return True

    async def load(self) -> None:
        """Embedded store: restore the snapshot and journal written by a former run."""
        if self.journal is None:
            return
        counts = await self.journal.restore(self._db)
        if counts:
            log.info("embedded store restored from %s: %s", self.journal.path, counts)

    async def close(self) -> None:
        if self.journal is not None:
            await self.journal.flush()
            await self.journal.compact(self._db)
        close = getattr(self._client, "close", None)
        if close is not None:
            result = close()
            if hasattr(result, "__await__"):
                await result


def open_store(settings: Settings) -> Store:
    """Build the store for these settings. Call inside the app's lifespan (event loop)."""
    if settings.mongo_url is not None:
        from pymongo import AsyncMongoClient

        timeout = settings.store_timeout_ms
        client: Any = AsyncMongoClient(
            settings.mongo_url.get_secret_value(),
            serverSelectionTimeoutMS=timeout,
            connectTimeoutMS=timeout,
            socketTimeoutMS=max(timeout, 10_000),
            tz_aware=True,
            journal=True,
        )
        return Store(settings, client, embedded=False)

    import mongomock_motor

    client = mongomock_motor.AsyncMongoMockClient(tz_aware=True)
    store = Store(settings, client, embedded=True)
    store.journal = Journal(settings.snapshot_path)
    return store
