"""The embedded store's collections: mongomock-motor's in-process collections, read and
written by ``_id`` and by ordered indexes (the store, its journal and snapshot:
:mod:`server.storage.embedded`).

mongomock answers every query by scanning its whole collection, so a collection
keeps its own ordered indexes (:mod:`server.storage.embedded_index`) of the fields
the repositories declare with :meth:`Collection.create_index`, plans the few query
shapes the repositories use on them, and reads and writes mongomock's document
table by ``_id``; anything else falls back to a scan with mongomock's own filter
matching, so the answers are the same as MongoDB's, only slower. Documents come
back as the driver gives them (datetimes UTC-aware, truncated to the millisecond
as BSON stores them). Each write is journaled through its store (:class:`Journaled`).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
from typing import Any, Protocol

from bson import ObjectId

from server.storage.base import Collection, Doc, Duplicate, Filter, SortSpec, update_doc
from server.storage.embedded_index import (
    _aware,
    _differ,
    _equal,
    _Index,
    _kept,
    _plain,
    _rank,
    _scalar,
    _shown,
    _stored,
)


class Journaled(Protocol):
    """What a collection asks of its store: a write's journal entry, made before the
    write (:class:`~server.storage.base.Rejected` when BSON cannot hold it, nothing
    changed), and recorded once the write is made (``None``: a write not journaled)."""

    def encode(self, op: str, coll: str, **fields: Any) -> bytes: ...

    def record(self, entry: bytes | None) -> None: ...


class EmbeddedCollection(Collection):
    """A mongomock collection, read and written by ``_id`` and by the ordered indexes."""

    def __init__(self, store: Journaled, raw: Any) -> None:
        self._store = store
        self.name = raw.name
        sync = raw.__dict__.get("_AsyncMongoMockCollection__collection", raw)
        self._sync = sync
        # mongomock's _id -> document table, as the plain mapping it keeps: its store
        # takes a lock and looks for expired documents at each access, and only the
        # event loop's thread reads or writes a collection (no TTL index is made here).
        self._table: dict[Any, Doc] = sync._store._documents
        self._indexes: dict[tuple[str, ...], _Index] = {}

    # -- reads ------------------------------------------------------------------------

    async def get(self, _id: Any) -> Doc | None:
        doc = self._table.get(_id)
        return None if doc is None else _aware(doc)

    async def get_many(self, ids: Iterable[Any]) -> list[Doc]:
        table = self._table
        return [_aware(doc) for i in ids if (doc := table.get(i)) is not None]

    async def find(
        self,
        flt: Filter | None = None,
        *,
        sort: SortSpec | None = None,
        limit: int = 0,
        projection: Mapping[str, Any] | None = None,
    ) -> list[Doc]:
        docs = self._select(_stored(dict(flt or {})), sort, limit)
        if not projection:
            return [_aware(d) for d in docs]
        # A projection makes a new document: only the values in it are copied.
        shown = _shown(projection)
        if shown is not None:  # the few fields it names are looked up, not every field
            return [{k: _aware(d[k]) for k in shown if k in d} for d in docs]
        keep = _kept(projection)
        return [{k: _aware(v) for k, v in d.items() if keep(k)} for d in docs]

    async def count(self, flt: Filter | None = None) -> int:
        if not flt:
            return len(self._table)
        return len(self._select(_stored(dict(flt)), None, 0))

    def _select(self, flt: Doc, sort: SortSpec | None, limit: int) -> list[Doc]:
        """The stored documents matching ``flt`` (stored form), sorted, at most ``limit``."""
        from mongomock.filtering import filter_applies, resolve_sort_key

        first = sort[0][0] if sort else None
        candidates, ordered_by = self._candidates(flt, first)
        # Candidates in the order of the sort's first field: with one field the first
        # ``limit`` matches are the answer; with more, the matches up to the last of the
        # ``limit``-th one's value of that field are all that can be.
        by_index = sort is not None and first is not None and first == ordered_by
        simple = by_index and sort is not None and len(sort) == 1
        if by_index and sort is not None and sort[0][1] < 0:
            candidates.reverse()
        out: list[Doc] = []
        plain = _plain(flt)
        table = self._table
        for _id in candidates:
            doc = table.get(_id)
            if doc is None or not (
                _equal(plain, doc) if plain is not None else filter_applies(flt, doc)
            ):
                continue
            if limit and by_index and len(out) >= limit and first is not None:
                if _differ(doc.get(first), out[limit - 1].get(first)):
                    break
            out.append(doc)
            if limit and (simple or not sort) and len(out) >= limit:
                return out
        if sort and not simple:
            for name, direction in reversed(list(sort)):

                def key(doc: Doc, name: str = name) -> Any:
                    return resolve_sort_key(name, doc)

                out.sort(key=key, reverse=direction < 0)
        return out[:limit] if limit else out

    def _candidates(self, flt: Doc, sort_by: str | None) -> tuple[list[Any], str | None]:
        """The ``_id``\\ s worth matching against ``flt`` and the field they are ordered by
        (``None``: no order), from the narrowest index (of two as narrow, the one ordered
        by ``sort_by``); every document when none helps."""
        key = flt.get("_id")
        if key is not None and _scalar(key):
            return [key], None
        if isinstance(key, dict) and set(key) == {"$in"}:
            return list(dict.fromkeys(key["$in"])), None
        best: tuple[int, bool, Iterator[Any], str] | None = None
        for index in self._indexes.values():
            plan = index.plan(flt)
            if plan is None:
                continue
            size, ids, field = plan
            rank = (size, field != sort_by)
            if best is None or rank < best[:2]:
                best = (size, field != sort_by, ids, field)
        if best is not None:
            return list(best[2]), best[3]
        return list(self._table), None

    # -- writes ------------------------------------------------------------------------

    def _put(self, doc: Doc, old: Doc | None) -> None:
        """Store ``doc`` (stored form) in place of ``old``, indexes kept in step (an index
        whose fields the change leaves alone is not touched: a contact write moves none)."""
        moved = [
            index
            for index in self._indexes.values()
            if old is None or any(_differ(old.get(f), doc.get(f)) for f in index.fields)
        ]
        for index in moved:
            index.check(doc)
        if old is not None:
            for index in moved:
                index.remove(old)
        self._table[doc["_id"]] = doc
        for index in moved:
            index.add(doc)

    def _drop(self, doc: Doc) -> None:
        for index in self._indexes.values():
            index.remove(doc)
        del self._table[doc["_id"]]

    async def insert(self, doc: Doc) -> None:
        self.insert_now(doc)

    def insert_now(self, doc: Doc, *, journal: bool = True) -> None:
        if "_id" not in doc:
            doc["_id"] = ObjectId()
        stored = _stored(doc)
        if doc["_id"] in self._table:
            raise Duplicate(f"E11000 duplicate key: {doc['_id']!r}")
        entry = self._store.encode("insert", self.name, docs=[stored]) if journal else None
        self._put(stored, None)
        self._store.record(entry)

    async def insert_many(self, docs: Sequence[Doc]) -> None:
        for doc in docs:
            self.insert_now(doc)

    async def update(
        self,
        flt: Filter,
        *,
        set: Mapping[str, Any] | None = None,
        max: Mapping[str, Any] | None = None,
        unset: Iterable[str] = (),
        upsert: bool = False,
    ) -> bool:
        return self.update_now(flt, update_doc(set, max, unset), upsert=upsert)

    def update_now(self, flt: Filter, update: Doc, *, upsert: bool, journal: bool = True) -> bool:
        spec = _stored(dict(flt))
        found = self._select(spec, None, 1)
        if not found:
            if not upsert:
                return False
            base = {k: v for k, v in spec.items() if not k.startswith("$") and _scalar(v)}
            doc = _apply(base, _stored(update))
            self.insert_now(_aware(doc), journal=journal)
            return True
        old = found[0]
        # A shallow copy will do: the update sets and unsets top-level fields only, and
        # a stored document's inner values are never changed in place (``_aware`` copies
        # them on every read).
        new = _apply(dict(old), _stored(update))
        if new != old:
            keyed = {"_id": old["_id"]}
            entry = (
                self._store.encode("update", self.name, flt=keyed, update=update)
                if journal
                else None
            )
            self._put(new, old)
            self._store.record(entry)
        return True

    async def replace(self, flt: Filter, doc: Doc, *, upsert: bool = False) -> bool:
        return self.replace_now(flt, doc, upsert=upsert)

    def replace_now(self, flt: Filter, doc: Doc, *, upsert: bool, journal: bool = True) -> bool:
        spec = _stored(dict(flt))
        found = self._select(spec, None, 1)
        if not found:
            if not upsert:
                return False
            new = dict(doc)
            if "_id" not in new and _scalar(spec.get("_id")) and "_id" in spec:
                new["_id"] = spec["_id"]
            self.insert_now(new, journal=journal)
            return True
        old = found[0]
        new = _stored({**doc, "_id": old["_id"]})
        entry = (
            self._store.encode("replace", self.name, flt={"_id": old["_id"]}, docs=[new])
            if journal
            else None
        )
        self._put(new, old)
        self._store.record(entry)
        return True

    async def delete(self, flt: Filter) -> int:
        return self.delete_now(flt)

    def delete_now(self, flt: Filter, *, journal: bool = True) -> int:
        gone = self._select(_stored(dict(flt)), None, 0)
        if not gone:
            return 0
        ids = [d["_id"] for d in gone]
        entry = (
            self._store.encode("delete", self.name, flt={"_id": {"$in": ids}}) if journal else None
        )
        for doc in gone:
            self._drop(doc)
        self._store.record(entry)
        return len(gone)

    async def create_index(self, keys: SortSpec, *, unique: bool = False) -> None:
        name = tuple(f for f, _ in keys)
        if name in self._indexes:
            return
        index = _Index(keys, unique)
        for doc in self._table.values():
            index.check(doc)
            index.add(doc)
        self._indexes[name] = index

    def documents(self) -> list[Doc]:
        """Every stored document (stored form), for the journal's snapshot."""
        return list(self._table.values())


def _apply(doc: Doc, update: Mapping[str, Any]) -> Doc:
    """``$set``, ``$max`` and ``$unset`` of top-level fields (what the repositories use)."""
    for op, fields in update.items():
        if op == "$set":
            doc.update(fields)
        elif op == "$max":
            for name, value in fields.items():
                if name not in doc or doc[name] is None or _rank(value) > _rank(doc[name]):
                    doc[name] = value
        elif op == "$unset":
            for name in fields:
                doc.pop(name, None)
        else:
            raise NotImplementedError(f"the embedded store does not apply {op}")
    return doc
