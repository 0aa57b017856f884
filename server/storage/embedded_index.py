"""The embedded store's values and ordered indexes (:mod:`server.storage.embedded_collection`).

How a document is held (the stored form: BSON's datetimes and binaries) and
given back (the driver's form), what a projection keeps of it, how two
values order as BSON orders them, the equalities matched without mongomock,
and :class:`_Index`, an ordered index of one or two fields that plans the
query shapes the repositories use.
"""

from __future__ import annotations

import operator
from collections.abc import Callable, Iterator, Mapping
from datetime import UTC, datetime
from typing import Any

from bson import Binary, ObjectId
from sortedcontainers import SortedList

from server.storage.base import Doc, Duplicate, Filter, SortSpec


def _stored(value: Any) -> Any:
    """A value as BSON would hold it: datetimes naive UTC, millisecond precision."""
    if isinstance(value, dict):
        return {k: _stored(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_stored(v) for v in value]
    if isinstance(value, datetime):
        if value.tzinfo is not None:
            value = value.astimezone(UTC).replace(tzinfo=None)
        return value.replace(microsecond=value.microsecond // 1000 * 1000)
    if type(value) is Binary and value.subtype == 0:
        return bytes(value)  # as the driver reads it back (and a plain value to the collector)
    return value


def _aware(value: Any) -> Any:
    """A stored value as the driver returns it (``tz_aware``): datetimes in UTC. A copy:
    every dict and list is new, and the rest (str, bytes, numbers, datetimes, ids) cannot
    be changed in place, so the stored document is never shared with a caller."""
    if isinstance(value, datetime):
        return value.replace(tzinfo=UTC)
    if isinstance(value, dict):
        return {k: _aware(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_aware(v) for v in value]
    return value


def _shown(projection: Mapping[str, Any]) -> tuple[str, ...] | None:
    """The top-level fields an inclusion projection shows, ``_id`` first unless hidden (in
    this order, where the driver keeps the document's); None for one that only hides."""
    shown = tuple(k for k, v in projection.items() if v and k != "_id")
    if not shown and not projection.get("_id"):
        return None
    return (("_id",) if projection.get("_id", 1) else ()) + shown


def _kept(projection: Mapping[str, Any]) -> Callable[[str], bool]:
    """Whether a projection keeps a top-level field: the fields it shows (and ``_id``
    unless hidden), or every field but those it hides."""
    shown = {k for k, v in projection.items() if v}
    hidden = {k for k, v in projection.items() if not v}
    if shown:
        return (shown | ({"_id"} if "_id" not in hidden else set())).__contains__
    return lambda k: k not in hidden


def _rank(value: Any) -> tuple[int, Any]:
    """A sort key that orders values of different types as BSON does."""
    from mongomock.filtering import _get_compare_type

    if value is None:
        return (5, 0)
    return (_get_compare_type(value), value)


#: BSON's rank of an ObjectId among types (mongomock's order).
_OID_RANK = 35


def _id_entry(_id: Any) -> tuple[tuple[int, Any], Any]:
    """An ``_id``'s rank and key in an index entry. An ObjectId is held as its 12 bytes
    (which order as it does): an entry of plain values is one the collector stops
    scanning, and a telemetry bucket makes three entries a second per vehicle."""
    if type(_id) is ObjectId:
        raw = _id.binary
        return (_OID_RANK, raw), raw
    return _rank(_id), _id


def _id_of(item: tuple[Any, ...]) -> Any:
    """The ``_id`` an index entry stands for."""
    return ObjectId(item[2]) if item[1][0] == _OID_RANK and type(item[2]) is bytes else item[2]


_RANGE_OPS = {"$gt": operator.gt, "$gte": operator.ge, "$lt": operator.lt, "$lte": operator.le}


def _differ(a: Any, b: Any) -> bool:
    """Whether an index must see a field move from ``a`` to ``b`` (1 and True are equal
    in Python, not in BSON's order)."""
    return type(a) is not type(b) or a != b


#: Values an equality can be matched on without mongomock: a stored value equal to one
#: of these is of the same type (an int could equal a bool or a float, which BSON tells
#: apart, and a list matches when it holds the value).
_PLAIN_TYPES = (str, datetime, type(None))


def _plain(flt: Doc) -> list[tuple[str, Any]] | None:
    """``flt`` as ``(field, value)`` pairs when it is only equalities on top-level fields
    with :data:`_PLAIN_TYPES` values (``{"finished_at": None}``), else None."""
    pairs = []
    for key, value in flt.items():
        if not isinstance(value, _PLAIN_TYPES) or "." in key or key.startswith("$"):
            return None
        pairs.append((key, value))
    return pairs


def _equal(pairs: list[tuple[str, Any]], doc: Doc) -> bool:
    """Whether ``doc`` matches the equalities of :func:`_plain` as MongoDB matches them
    (a missing field equals None); an array field is left to mongomock."""
    for key, value in pairs:
        held = doc.get(key)
        if type(held) is list:
            from mongomock.filtering import filter_applies

            return bool(filter_applies(dict(pairs), doc))
        if held != value:
            return False
    return True


def _scalar(value: Any) -> bool:
    return not isinstance(value, dict | list | tuple)


class _Index:
    """An ordered index of one or two fields, kept beside mongomock's table.

    One field: every document ordered by it. Two: per value of the first
    (an equality in the queries that use it), the documents ordered by the
    second. Values that cannot be ordered (documents, arrays) are left out,
    and a query on them scans.
    """

    def __init__(self, keys: SortSpec, unique: bool) -> None:
        self.fields = [name for name, _ in keys]
        self.unique = unique
        self.first = self.fields[0]
        self.second = self.fields[1] if len(self.fields) > 1 else None
        self.ordered: SortedList | None = SortedList() if self.second is None else None
        self.groups: dict[Any, SortedList] = {}
        self.keys: dict[tuple[Any, ...], Any] = {}  # unique: key -> _id

    def _entry(self, doc: Doc) -> tuple[Any, tuple[Any, ...]] | None:
        first = doc.get(self.first)
        if not _scalar(first):
            return None
        if self.second is None:
            return None, (_rank(first), *_id_entry(doc["_id"]))
        second = doc.get(self.second)
        if not _scalar(second):
            return None
        return first, (_rank(second), *_id_entry(doc["_id"]))

    def unique_key(self, doc: Doc) -> tuple[Any, ...]:
        return tuple(repr(_rank(doc.get(f))) for f in self.fields)

    def check(self, doc: Doc) -> None:
        if self.unique and self.keys.get(self.unique_key(doc), doc["_id"]) != doc["_id"]:
            raise Duplicate(f"E11000 duplicate key on {self.fields}")

    def add(self, doc: Doc) -> None:
        if self.unique:
            self.keys[self.unique_key(doc)] = doc["_id"]
        entry = self._entry(doc)
        if entry is None:
            return
        group, item = entry
        if self.ordered is not None:
            self.ordered.add(item)
        else:
            self.groups.setdefault(group, SortedList()).add(item)

    def remove(self, doc: Doc) -> None:
        if self.unique:
            self.keys.pop(self.unique_key(doc), None)
        entry = self._entry(doc)
        if entry is None:
            return
        group, item = entry
        if self.ordered is not None:
            self.ordered.discard(item)
            return
        members = self.groups.get(group)
        if members is not None:
            members.discard(item)
            if not members:
                del self.groups[group]

    def plan(self, flt: Filter) -> tuple[int, Iterator[Any], str] | None:
        """Candidate ``_id``\\ s for ``flt`` in the order of the index's last field: how
        many at most, the ids, and the field they are ordered by. ``None`` when this
        index does not narrow ``flt``."""
        if self.ordered is not None:
            members, field = self.ordered, self.first
        else:
            value = flt.get(self.first)
            if (value is None and self.first not in flt) or not _scalar(value):
                return None
            members = self.groups.get(value, SortedList())
            field = self.second or self.first
        cond = flt.get(field)
        lo, hi = 0, len(members)
        if isinstance(cond, dict) and cond and set(cond) <= set(_RANGE_OPS):
            for op, bound in cond.items():
                if not _scalar(bound):
                    return None
                key = (_rank(_stored(bound)),)
                # A range matches values of its bound's type only (BSON's type brackets,
                # which mongomock's matching follows): a null is never below a date.
                bracket = key[0][0]
                lo = max(lo, members.bisect_left(((bracket,),)))
                hi = min(hi, members.bisect_left(((bracket + 1,),)))
                if op in ("$gt", "$gte"):
                    at = members.bisect_right((*key, (99,))) if op == "$gt" else None
                    lo = max(lo, at if at is not None else members.bisect_left(key))
                else:
                    at = members.bisect_left(key) if op == "$lt" else None
                    hi = min(hi, at if at is not None else members.bisect_right((*key, (99,))))
        elif cond is not None and _scalar(cond):
            key = (_rank(_stored(cond)),)
            lo, hi = members.bisect_left(key), members.bisect_right((*key, (99,)))
        elif self.ordered is not None:
            return None  # a one-field index narrows nothing without a condition on it
        hi = max(lo, hi)
        return hi - lo, (_id_of(item) for item in members.islice(lo, hi)), field
