"""The two storage backends behind one interface (:mod:`server.storage.base`), and the
choice between them (:func:`open_store`).

- **MongoDB** (``FLEET_MONGO_URL``): PyMongo's ``AsyncMongoClient``, created in the
  app's lifespan. Every write carries the configured write concern (default
  ``w: "majority", j: true``); a write it acknowledged is durable.
- **Embedded** (no URL): :mod:`server.storage.embedded`, mongomock-motor's
  in-process collections with a journal and ordered indexes of its own.

Repositories see :class:`Collection` and :class:`Store` alone: the same calls,
the same errors (:class:`Duplicate`, :class:`Rejected`,
:class:`~server.errors.Unavailable`), the same documents (datetimes UTC-aware,
truncated to the millisecond as BSON stores them).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping, Sequence
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


class MongoCollection(Collection):
    def __init__(self, raw: Any) -> None:
        self._raw = raw
        self.name = raw.name

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
        async with _GUARD:
            result = await self._raw.update_one(dict(flt), update, upsert=upsert)
        return bool(result.matched_count) or result.upserted_id is not None

    async def replace(self, flt: Filter, doc: Doc, *, upsert: bool = False) -> bool:
        async with _GUARD:
            result = await self._raw.replace_one(dict(flt), doc, upsert=upsert)
        return bool(result.matched_count) or result.upserted_id is not None

    async def delete(self, flt: Filter) -> int:
        async with _GUARD:
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

    def _open(self, name: str) -> Collection:
        return MongoCollection(self._db[name])

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
