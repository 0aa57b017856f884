"""The two storage backends behind one interface (:mod:`server.storage.base`), and the
choice between them (:func:`open_store`).

- **MongoDB** (``FLEET_MONGO_URL``): PyMongo's ``AsyncMongoClient``, created in the
  app's lifespan. Every write carries the configured write concern (default
  ``w: "majority", j: true``); a write it acknowledged is durable. The repositories'
  compare-and-set writes need a single-document write to be atomic, as MongoDB's is;
  FerretDB 1.x's is not, and there each such write holds a lock in the store
  (:class:`_DocLocks`).
- **Embedded** (no URL): :mod:`server.storage.embedded`, mongomock-motor's
  in-process collections with a journal and ordered indexes of its own.

Repositories see :class:`Collection` and :class:`Store` alone: the same calls,
the same errors (:class:`Duplicate`, :class:`Rejected`,
:class:`~server.errors.Unavailable`), the same documents (datetimes UTC-aware,
truncated to the millisecond as BSON stores them).
"""

from __future__ import annotations

import asyncio
import logging
import secrets
import time
from collections.abc import AsyncIterator, Iterable, Mapping, Sequence
from contextlib import asynccontextmanager
from datetime import UTC, datetime, timedelta
from typing import Any

from pymongo.errors import (
    BulkWriteError,
    ConnectionFailure,
    DuplicateKeyError,
    OperationFailure,
    PyMongoError,
    WriteError,
)

from server.errors import Unavailable
from server.settings import Settings
from server.storage.base import (
    ENCODE_ERRORS,
    Collection,
    Doc,
    Duplicate,
    Filter,
    Rejected,
    SortSpec,
    Store,
    update_doc,
)
from server.storage.embedded import EmbeddedStore

__all__ = [
    "ENCODE_ERRORS",
    "Collection",
    "Doc",
    "Duplicate",
    "EmbeddedStore",
    "Filter",
    "MongoStore",
    "Rejected",
    "SortSpec",
    "Store",
    "open_store",
]

log = logging.getLogger("fleet.storage")

_DUPLICATE = 11000


# ---- MongoDB ----------------------------------------------------------------------


class _MongoCall:
    """Turns the driver's errors into the store's: unreachable -> 503, the record's
    fault -> :class:`Rejected`, a taken key -> :class:`Duplicate`."""

    async def __aenter__(self) -> None:
        return None

    async def __aexit__(self, exc_type: Any, exc: BaseException | None, tb: Any) -> bool:
        if exc is None:
            return False
        if isinstance(exc, DuplicateKeyError):
            raise Duplicate(str(exc)) from exc
        if isinstance(exc, BulkWriteError):
            errors = exc.details.get("writeErrors") or []
            if errors and all(e.get("code") == _DUPLICATE for e in errors):
                raise Duplicate(str(errors[0].get("errmsg", "duplicate key"))) from exc
            raise Rejected(str(errors[0].get("errmsg", exc)) if errors else str(exc)) from exc
        if isinstance(exc, WriteError):
            raise Rejected(str(exc)) from exc
        if isinstance(exc, ENCODE_ERRORS):
            raise Rejected(f"{type(exc).__name__}: {exc}") from exc
        if isinstance(exc, ConnectionFailure):
            raise Unavailable("the store cannot be reached; try again shortly") from exc
        if isinstance(exc, OperationFailure):
            return False  # a bug of ours (a query the server refuses): let it show
        if isinstance(exc, PyMongoError):
            raise Unavailable(f"the store failed: {type(exc).__name__}") from exc
        return False


_GUARD = _MongoCall()

#: A document lock held longer than this was left by a replica that died: taken over.
LOCK_STALE_S = 5.0
#: How long a write waits for a document's lock before the store is called busy (503).
LOCK_WAIT_S = 10.0


class _DocLocks:
    """FerretDB 1.x (over SQLite) applies an update or a replace as a read, then a write of
    the whole document, not as one step: two compare-and-set writes of one document both
    match (measured on 1.24.2: four at once, several won in 198 races of 200), and a
    write of one field can undo another's. So on FerretDB each single-document write
    (update, replace, a delete with a condition) holds the document's lock: a document
    of ``_doc_locks`` whose ``_id`` names the collection and the document, inserted (a
    unique key is atomic there), deleted after the write. A lock left by a replica that
    died is taken over after :data:`LOCK_STALE_S`. MongoDB writes one document
    atomically: no lock is taken there. Which server it is, ``buildInfo`` says
    (``ferretdbVersion``), asked once."""

    def __init__(self, db: Any) -> None:
        self._db = db
        self._locks: Any = None
        self._known = False
        self._asking = asyncio.Lock()

    async def needed(self) -> bool:
        if not self._known:
            async with self._asking:
                if not self._known:
                    async with _GUARD:
                        info = await self._db.client.admin.command("buildInfo")
                    if "ferretdbVersion" in info:
                        self._locks = self._db["_doc_locks"]
                    self._known = True
        return self._locks is not None

    @asynccontextmanager
    async def held(self, collection: str, _id: Any) -> AsyncIterator[None]:
        key, token = f"{collection}/{_id}", secrets.token_hex(8)
        deadline = time.monotonic() + LOCK_WAIT_S
        pause = 0.002
        while True:
            try:
                async with _GUARD:
                    await self._locks.insert_one({"_id": key, "token": token, "at": _now()})
                break
            except BaseException as exc:
                if not isinstance(exc, Duplicate):
                    # Cut off (cancelled, the store away) when the insert may have been
                    # made: let go of it, whatever happened, before giving up.
                    await self._let_go(key, token)
                    raise
                left = _now() - timedelta(seconds=LOCK_STALE_S)
                async with _GUARD:
                    taken = await self._locks.delete_one({"_id": key, "at": {"$lt": left}})
                if taken.deleted_count:
                    log.warning("store: took over the lock left on %s", key)
                    continue
                if time.monotonic() > deadline:
                    raise Unavailable("the store is busy with this record; try again") from None
                await asyncio.sleep(pause)
                pause = min(pause * 2, 0.05)
        try:
            yield
        finally:
            await self._let_go(key, token)

    async def _let_go(self, key: str, token: str) -> None:
        """The lock deleted, if it is ours, even when the task is cancelled meanwhile (a
        lock left would hold every writer of the document up for LOCK_STALE_S)."""
        release = asyncio.ensure_future(self._locks.delete_one({"_id": key, "token": token}))
        try:
            await asyncio.shield(release)
        except PyMongoError as exc:  # the store away: the lock is taken over when stale
            log.warning("store: a lock on %s not let go of: %s", key, type(exc).__name__)


def _now() -> datetime:
    return datetime.now(UTC)


def _one_document(flt: Filter, *, any_condition: bool) -> Any:
    """The ``_id`` a write with this filter is to one document of (None: not so, or,
    unless ``any_condition``, a filter of the ``_id`` alone)."""
    _id = flt.get("_id")
    if _id is None or isinstance(_id, Mapping):
        return None
    return _id if any_condition or len(flt) > 1 else None


class MongoCollection(Collection):
    def __init__(self, raw: Any, locks: _DocLocks) -> None:
        self._raw = raw
        self._doc_locks = locks
        self.name = raw.name

    @asynccontextmanager
    async def _locked(self, flt: Filter, *, any_condition: bool = True) -> AsyncIterator[None]:
        """The document's lock held, where the server needs it (:class:`_DocLocks`)."""
        _id = _one_document(flt, any_condition=any_condition)
        if _id is None or not await self._doc_locks.needed():
            yield
            return
        async with self._doc_locks.held(self.name, _id):
            yield

    async def get(self, _id: Any) -> Doc | None:
        async with _GUARD:
            doc: Doc | None = await self._raw.find_one({"_id": _id})
        return doc

    async def get_many(self, ids: Iterable[Any]) -> list[Doc]:
        wanted = list(ids)
        if not wanted:
            return []
        return await self.find({"_id": {"$in": wanted}})

    async def insert(self, doc: Doc) -> None:
        async with _GUARD:
            await self._raw.insert_one(doc)

    async def insert_many(self, docs: Sequence[Doc]) -> None:
        if docs:
            async with _GUARD:
                await self._raw.insert_many(list(docs), ordered=True)

    async def find(
        self,
        flt: Filter | None = None,
        *,
        sort: SortSpec | None = None,
        limit: int = 0,
        projection: Mapping[str, Any] | None = None,
    ) -> list[Doc]:
        async with _GUARD:
            cursor = self._raw.find(dict(flt or {}), projection)
            if sort:
                cursor = cursor.sort(list(sort))
            if limit:
                cursor = cursor.limit(limit)
            docs: list[Doc] = await cursor.to_list(None)
        return docs

    async def update(
        self,
        flt: Filter,
        *,
        set: Mapping[str, Any] | None = None,
        max: Mapping[str, Any] | None = None,
        unset: Iterable[str] = (),
        upsert: bool = False,
    ) -> bool:
        update = update_doc(set, max, unset)
        if not update:
            return await self.count(flt) > 0
        async with self._locked(flt), _GUARD:
            result = await self._raw.update_one(dict(flt), update, upsert=upsert)
        return bool(result.matched_count) or result.upserted_id is not None

    async def replace(self, flt: Filter, doc: Doc, *, upsert: bool = False) -> bool:
        async with self._locked(flt), _GUARD:
            result = await self._raw.replace_one(dict(flt), doc, upsert=upsert)
        return bool(result.matched_count) or result.upserted_id is not None

    async def delete(self, flt: Filter) -> int:
        # A delete by ``_id`` alone is atomic on FerretDB too; one with a condition must
        # not run between another write's read and write.
        async with self._locked(flt, any_condition=False), _GUARD:
            result = await self._raw.delete_many(dict(flt))
        return int(result.deleted_count)

    async def count(self, flt: Filter | None = None) -> int:
        async with _GUARD:
            n = await self._raw.count_documents(dict(flt or {}))
        return int(n)

    async def create_index(self, keys: SortSpec, *, unique: bool = False) -> None:
        async with _GUARD:
            await self._raw.create_index(list(keys), unique=unique)


class MongoStore(Store):
    kind = "mongodb"
    durable_on_write = True

    def __init__(
        self, url: str, db_name: str, *, timeout_ms: int, write_w: int | str, journal: bool
    ) -> None:
        super().__init__()
        self.durability = f"w={write_w}, j={str(journal).lower()}"
        from pymongo import AsyncMongoClient

        self._client: Any = AsyncMongoClient(
            url,
            serverSelectionTimeoutMS=timeout_ms,
            connectTimeoutMS=timeout_ms,
            socketTimeoutMS=max(timeout_ms, 10_000),
            tz_aware=True,
            w=write_w,
            journal=journal,
        )
        self._db = self._client[db_name]
        self._doc_locks = _DocLocks(self._db)

    def _open(self, name: str) -> Collection:
        return MongoCollection(self._db[name], self._doc_locks)

    async def ping(self) -> str | None:
        try:
            await self._client.admin.command("ping")
        except PyMongoError as exc:
            return f"MongoDB unreachable: {type(exc).__name__}"
        return None

    async def close(self) -> None:
        await self._client.close()


def open_store(settings: Settings) -> Store:
    """The store the settings name. Call inside the app's lifespan (event loop)."""
    if settings.mongo_url is not None:
        w = settings.store_write_concern
        return MongoStore(
            settings.mongo_url.get_secret_value(),
            settings.db_name,
            timeout_ms=settings.store_timeout_ms,
            write_w=int(w) if w.isdigit() else w,
            journal=settings.store_journal,
        )
    return EmbeddedStore(settings.db_name, settings.snapshot_path)
