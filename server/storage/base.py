"""The storage interface the repositories see: :class:`Collection` and :class:`Store`,
the errors (:class:`Duplicate`, :class:`Rejected`), the document types, and the one
shape of an update both backends apply (:func:`update_doc`). The backends are
:mod:`server.storage.backends` (MongoDB, and the choice of backend) and
:mod:`server.storage.embedded`."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import bson

Doc = dict[str, Any]
Filter = Mapping[str, Any]
SortSpec = Sequence[tuple[str, int]]

#: What BSON encoding raises for a value it cannot hold (integers past 64 bits,
#: lone surrogates, NUL in keys, ...).
ENCODE_ERRORS = (bson.errors.InvalidDocument, OverflowError, UnicodeEncodeError, ValueError)


class Duplicate(Exception):
    """A document with this ``_id`` (or unique key) is stored already."""


class Rejected(Exception):
    """The store cannot hold this record: it is the record's fault, not the store's."""


class Collection(ABC):
    """One collection, with the calls the repositories make."""

    name: str

    @abstractmethod
    async def get(self, _id: Any) -> Doc | None:
        """The document with this ``_id``."""

    @abstractmethod
    async def get_many(self, ids: Iterable[Any]) -> list[Doc]:
        """The documents with these ``_id``\\ s that exist (in no set order)."""

    @abstractmethod
    async def insert(self, doc: Doc) -> None:
        """Insert ``doc`` (``_id`` filled in when missing). :class:`Duplicate` if taken."""

    @abstractmethod
    async def insert_many(self, docs: Sequence[Doc]) -> None:
        """Insert in order; :class:`Duplicate` at the first taken key (those before stay)."""

    @abstractmethod
    async def find(
        self,
        flt: Filter | None = None,
        *,
        sort: SortSpec | None = None,
        limit: int = 0,
        projection: Mapping[str, Any] | None = None,
    ) -> list[Doc]:
        """The matching documents."""

    async def find_one(self, flt: Filter, *, sort: SortSpec | None = None) -> Doc | None:
        docs = await self.find(flt, sort=sort, limit=1)
        return docs[0] if docs else None

    @abstractmethod
    async def update(
        self,
        flt: Filter,
        *,
        set: Mapping[str, Any] | None = None,
        max: Mapping[str, Any] | None = None,
        unset: Iterable[str] = (),
        upsert: bool = False,
    ) -> bool:
        """Change the first matching document (``$set``, ``$max``, ``$unset`` of top-level
        fields); with ``upsert``, insert one when none matches. Whether one matched or
        was inserted."""

    @abstractmethod
    async def replace(self, flt: Filter, doc: Doc, *, upsert: bool = False) -> bool:
        """Replace the first matching document; whether one matched or was inserted."""

    @abstractmethod
    async def delete(self, flt: Filter) -> int:
        """Delete every matching document; how many."""

    @abstractmethod
    async def count(self, flt: Filter | None = None) -> int: ...

    @abstractmethod
    async def create_index(self, keys: SortSpec, *, unique: bool = False) -> None: ...


class Store(ABC):
    """The database: collections by name, readiness, durability."""

    #: ``embedded`` or ``mongodb`` (``/readyz`` says which).
    kind: str
    #: Whether an acknowledged write is durable (MongoDB); else after :meth:`flush`.
    durable_on_write: bool
    #: What makes a write durable, for people (``/readyz``).
    durability: str

    def __init__(self) -> None:
        self._collections: dict[str, Collection] = {}

    def __getitem__(self, name: str) -> Collection:
        coll = self._collections.get(name)
        if coll is None:
            coll = self._collections[name] = self._open(name)
        return coll

    @abstractmethod
    def _open(self, name: str) -> Collection: ...

    @abstractmethod
    async def ping(self) -> str | None:
        """``None`` when the store answers, else why not."""

    async def load(self) -> None:  # noqa: B027 - a store with nothing to load does nothing
        """Take up what a former run stored (the embedded store's files)."""

    async def flush(self) -> bool:
        """Make every write so far durable; whether anything was written."""
        return False

    async def make_durable(self) -> bool:
        """Every write so far durable before an answer says it was taken (a command
        accepted, a vehicle's ack): only the writes themselves, never a compaction.
        False when that cannot be done now (logged; durable at the first flush that
        works): the caller answers all the same, never with an error."""
        return True  # an acknowledged write is durable already

    async def close(self) -> None:  # noqa: B027 - nothing to close by default
        """Let go of the connection; the embedded store writes its snapshot."""


def update_doc(
    set: Mapping[str, Any] | None, max: Mapping[str, Any] | None, unset: Iterable[str]
) -> Doc:
    """The ``$set`` / ``$max`` / ``$unset`` document of :meth:`Collection.update`."""
    update: Doc = {}
    if set:
        update["$set"] = dict(set)
    if max:
        update["$max"] = dict(max)
    gone = list(unset)
    if gone:
        update["$unset"] = dict.fromkeys(gone, "")
    return update
