"""Telemetry buckets: one document per vehicle per time window, written whole, never updated.

A bucket is ``{vehicle_id, start, end, min_seq, max_seq, n, samples}``
where ``start``/``end`` are the earliest and latest sample ``ts`` in it and
the samples are in ``seq`` order, packed as one BSON binary (read them with
:func:`samples_of`): queries select buckets by their metadata only, and a
packed bucket costs a tenth of the memory of a list of documents and is
inserted without the driver walking every field. The buckets one replica writes
for a vehicle hold disjoint, rising ``seq`` ranges (the service writes them in
order). With several replicas a sample the vehicle sent to two of them may be
stored twice (docs/live.md, "Several replicas"); reads go through
:func:`distinct_samples`, which gives each ``seq`` once. Index
``(vehicle_id, start)``; no unique index, no ``$group``, no ``update_one``
(see ARCHITECTURE.md, Storage).

Real MongoDB answers every query with its indexes. The embedded store
(mongomock) scans the whole collection on every query, so on it this module
keeps an in-process index of bucket metadata and reads buckets by ``_id``
straight from mongomock's document table: a query then costs what it
returns, not what is stored. The index is rebuilt from the collection on
:meth:`TelemetryRepo.load`; every insert and delete goes through
:class:`~server.storage.driver.Collection` or the journal, so it stays
durable.
"""

from __future__ import annotations

import bisect
import heapq
import itertools
import logging
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import bson

from server.storage.driver import Doc, Store

log = logging.getLogger("fleet.storage")

COLLECTION = "telemetry"
_META = {"samples": 0}
_MIN = datetime.min.replace(tzinfo=UTC)
_MAX = datetime.max.replace(tzinfo=UTC)


_CODEC: bson.CodecOptions[Any] = bson.CodecOptions(tz_aware=True)


def pack(samples: list[Doc]) -> bson.Binary:
    return bson.Binary(bson.encode({"s": samples}))


def samples_of(bucket: Mapping[str, Any]) -> list[Doc]:
    """A bucket's samples, in ``seq`` order (packed, or a list in older stores)."""
    raw = bucket["samples"]
    if isinstance(raw, bytes):
        samples: list[Doc] = bson.decode(raw, _CODEC)["s"]
        return samples
    return list(raw)


def distinct_samples(buckets: Iterable[Mapping[str, Any]]) -> Iterator[Doc]:
    """The samples of ``buckets`` in ``seq`` order, each ``seq`` once.

    Buckets whose ``seq`` ranges overlap no other (all of them, on one replica)
    are read as they are, one after the other: no cost per sample. Overlapping
    ones are merged by ``seq`` and, of two copies of one ``seq``, the copy in
    the bucket inserted first (lowest ``_id``: an ObjectId begins with its
    insert time) is kept.
    """
    group: list[Mapping[str, Any]] = []
    reach = 0  # highest max_seq in the group
    for bucket in sorted(buckets, key=lambda b: int(b["min_seq"])):
        if group and bucket["min_seq"] <= reach:
            group.append(bucket)
            reach = max(reach, int(bucket["max_seq"]))
            continue
        yield from _merged(group)
        group = [bucket]
        reach = int(bucket["max_seq"])
    yield from _merged(group)


def _merged(group: list[Mapping[str, Any]]) -> Iterator[Doc]:
    if len(group) <= 1:
        for bucket in group:
            yield from samples_of(bucket)
        return
    # heapq.merge takes equal keys from the earlier input first: the first inserted.
    runs = [samples_of(b) for b in sorted(group, key=_inserted)]
    last = None
    for sample in heapq.merge(*runs, key=lambda s: int(s["seq"])):
        if sample["seq"] != last:
            last = sample["seq"]
            yield sample


def _inserted(bucket: Mapping[str, Any]) -> str:
    """Insert order of a bucket: its ObjectId as hex sorts as the ObjectId does."""
    return str(bucket.get("_id", ""))


def aware(value: datetime) -> datetime:
    """Stored datetimes come back naive from the embedded store's table: they are UTC."""
    return value if value.tzinfo is not None else value.replace(tzinfo=UTC)


@dataclass(slots=True)
class BucketMeta:
    id: Any
    vehicle_id: str
    start: datetime
    end: datetime
    min_seq: int
    max_seq: int
    n: int

    @classmethod
    def of(cls, doc: Mapping[str, Any]) -> BucketMeta:
        return cls(
            doc["_id"],
            doc["vehicle_id"],
            aware(doc["start"]),
            aware(doc["end"]),
            int(doc["min_seq"]),
            int(doc["max_seq"]),
            int(doc["n"]),
        )

    def overlaps(self, start: datetime, end: datetime) -> bool:
        """Whether a sample of this bucket may lie in ``[start, end)``."""
        return self.start < end and self.end >= start


class _VehicleIndex:
    """One vehicle's buckets in ``min_seq`` order, and the running highest ``max_seq``.

    ``reach[i]`` is the highest ``max_seq`` of ``metas[: i + 1]``: it never falls,
    so it can be bisected even where two replicas' buckets overlap.
    """

    __slots__ = ("metas", "reach")

    def __init__(self) -> None:
        self.metas: list[BucketMeta] = []
        self.reach: list[int] = []

    def add(self, meta: BucketMeta) -> None:
        if self.metas and meta.min_seq < self.metas[-1].min_seq:
            # Out of order (never from one replica; restored data, or another replica's write).
            at = bisect.bisect_right(self.metas, meta.min_seq, key=lambda m: m.min_seq)
            self.metas.insert(at, meta)
            self._reach()
            return
        self.metas.append(meta)
        self.reach.append(max(self.reach[-1], meta.max_seq) if self.reach else meta.max_seq)

    def high(self) -> int:
        return self.reach[-1] if self.reach else -1

    def after_seq(self, after_seq: int) -> Iterator[BucketMeta]:
        """Buckets holding a ``seq`` above ``after_seq``, in ``min_seq`` order (lazily)."""
        for i in range(bisect.bisect_right(self.reach, after_seq), len(self.metas)):
            meta = self.metas[i]
            if meta.max_seq > after_seq:
                yield meta

    def drop(self, ids: set[Any]) -> None:
        self.metas = [m for m in self.metas if m.id not in ids]
        self._reach()

    def _reach(self) -> None:
        self.reach = list(itertools.accumulate((m.max_seq for m in self.metas), max))


class TelemetryRepo:
    def __init__(self, store: Store, *, use_index: bool | None = None) -> None:
        self.store = store
        self.coll = store[COLLECTION]
        table = self.coll.table if use_index is not False else None
        self._table = table
        self._index: dict[str, _VehicleIndex] | None = {} if table is not None else None

    @property
    def indexed(self) -> bool:
        return self._index is not None

    async def ensure_indexes(self) -> None:
        await self.coll.create_index([("vehicle_id", 1), ("start", 1)])
        await self.coll.create_index([("vehicle_id", 1), ("max_seq", 1)])
        await self.coll.create_index([("end", 1)])

    async def load(self) -> None:
        """Build the in-process index from what is stored (embedded store; one pass)."""
        if self._index is None or self._table is None:
            return
        self._index.clear()
        count = 0
        for doc in list(self._table.documents):
            self._vehicle(doc["vehicle_id"]).add(BucketMeta.of(doc))
            count += 1
        if count:
            log.info("telemetry: %d buckets of %d vehicles indexed", count, len(self._index))

    def _vehicle(self, vehicle_id: str) -> _VehicleIndex:
        assert self._index is not None
        entry = self._index.get(vehicle_id)
        if entry is None:
            entry = self._index[vehicle_id] = _VehicleIndex()
        return entry

    # ---- writes -------------------------------------------------------------
    @staticmethod
    def make_bucket(vehicle_id: str, samples: list[Doc]) -> Doc:
        """A bucket document for ``samples`` (stored form, ``seq`` order, not empty)."""
        times = [s["ts"] for s in samples]
        return {
            "vehicle_id": vehicle_id,
            "start": min(times),
            "end": max(times),
            "min_seq": samples[0]["seq"],
            "max_seq": samples[-1]["seq"],
            "n": len(samples),
            "samples": pack(samples),
        }

    async def insert(self, bucket: Doc) -> BucketMeta:
        await self.coll.append(bucket)  # fills bucket["_id"]; buckets have no unique index
        meta = BucketMeta.of(bucket)
        if self._index is not None:
            self._vehicle(meta.vehicle_id).add(meta)
        return meta

    async def insert_many(self, buckets: list[Doc]) -> None:
        """Bulk load (benchmarks, imports): one driver call."""
        await self.coll.insert_many(buckets)
        if self._index is not None:
            for bucket in buckets:
                self._vehicle(bucket["vehicle_id"]).add(BucketMeta.of(bucket))

    async def drop_ended_before(self, cutoff: datetime) -> int:
        """Retention: drop every bucket whose newest sample is older than ``cutoff``."""
        if self._index is None or self._table is None:
            return await self.coll.delete_many({"end": {"$lt": cutoff}})
        ids: set[Any] = set()
        for entry in self._index.values():
            old = {m.id for m in entry.metas if m.end < cutoff}
            if old:
                entry.drop(old)
                ids |= old
        for empty in [v for v, e in self._index.items() if not e.metas]:
            del self._index[empty]
        if not ids:
            return 0
        for _id in ids:
            if _id in self._table:
                del self._table[_id]
        # Journaled like any delete, so a restart does not bring them back.
        self.store.journal_op("delete", COLLECTION, flt={"_id": {"$in": sorted(ids)}})
        return len(ids)

    # ---- reads --------------------------------------------------------------
    def vehicles(self) -> list[str] | None:
        """Vehicles with stored buckets, when known without a query (embedded store)."""
        return None if self._index is None else list(self._index)

    async def max_seq(self, vehicle_id: str) -> int:
        """Highest stored ``seq`` of the vehicle; -1 when none."""
        if self._index is not None:
            entry = self._index.get(vehicle_id)
            return entry.high() if entry else -1
        docs = await self.coll.find(
            {"vehicle_id": vehicle_id}, sort=[("max_seq", -1)], limit=1, projection=_META
        )
        return int(docs[0]["max_seq"]) if docs else -1

    async def latest_sample(self, vehicle_id: str) -> Doc | None:
        """The stored sample with the greatest ``ts`` (it is in the bucket ending last;
        of two such buckets, copies of one sample, the one inserted first)."""
        if self._index is not None:
            entry = self._index.get(vehicle_id)
            if not entry or not entry.metas:
                return None
            end = max(m.end for m in entry.metas)
            last = min((m for m in entry.metas if m.end == end), key=lambda m: str(m.id))
            buckets = self._fetch([last])
        else:
            buckets = await self.coll.find(
                {"vehicle_id": vehicle_id}, sort=[("end", -1), ("_id", 1)], limit=1
            )
        if not buckets:
            return None
        return max(samples_of(buckets[0]), key=lambda s: (aware(s["ts"]), s["seq"]))

    async def in_window(self, vehicle_id: str, start: datetime, end: datetime) -> list[Doc]:
        """Buckets that may hold samples with ``start <= ts < end``, in ``seq`` order."""
        if self._index is not None:
            entry = self._index.get(vehicle_id)
            metas = [m for m in entry.metas if m.overlaps(start, end)] if entry else []
            return self._fetch(metas)
        return await self.coll.find(
            {"vehicle_id": vehicle_id, "start": {"$lt": end}, "end": {"$gte": start}},
            sort=[("min_seq", 1)],
        )

    async def after_seq(
        self,
        vehicle_id: str,
        after_seq: int,
        *,
        limit: int,
        start: datetime | None = None,
        end: datetime | None = None,
    ) -> list[Doc]:
        """Up to ``limit`` buckets holding samples with ``seq > after_seq``, in ``seq`` order
        (of ``max_seq`` on MongoDB, of ``min_seq`` in the index: read them with
        :func:`distinct_samples`).

        With ``start``/``end``, only buckets that may hold samples with ``start <= ts < end``.
        """
        if self._index is not None:
            entry = self._index.get(vehicle_id)
            metas = entry.after_seq(after_seq) if entry else iter(())
            if start is not None or end is not None:
                lo, hi = start or _MIN, end or _MAX
                metas = (m for m in metas if m.overlaps(lo, hi))
            return self._fetch(list(itertools.islice(metas, limit)))
        flt: Doc = {"vehicle_id": vehicle_id, "max_seq": {"$gt": after_seq}}
        if start is not None:
            flt["end"] = {"$gte": start}
        if end is not None:
            flt["start"] = {"$lt": end}
        return await self.coll.find(flt, sort=[("max_seq", 1)], limit=limit)

    def _fetch(self, metas: list[BucketMeta]) -> list[Doc]:
        """Stored documents by ``_id``, without a scan. Read-only: buckets never change."""
        assert self._table is not None
        return [self._table[m.id] for m in metas if m.id in self._table]
