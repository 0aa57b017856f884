"""Telemetry buckets: one document per vehicle per time window, written whole, never updated.

A bucket is ``{vehicle_id, start, end, min_seq, max_seq, n, bytes, samples}``
where ``start``/``end`` are the earliest and latest sample ``ts`` in it (the store
keeps their milliseconds, and those of a query's times alike) and the samples are
in ``seq`` order, packed as one binary (read them with :func:`samples_of`): queries
select buckets by their metadata only, and a packed bucket costs a tenth of the
memory of a list of documents and is inserted without the driver walking every
field. The packing is JSON text (orjson; binary subtype :data:`PACKED_JSON`), the times as
ISO 8601 with their microseconds: about a fifth of the time BSON takes to pack
and to read (an aware ``datetime`` is BSON's slowest value). Buckets stored
before it hold one BSON document ``{"s": [...]}`` (subtype 0) and are read as
such. A bucket holds at most the service's sample and byte bounds (well under
BSON's 16 MiB).

The buckets one replica writes for a vehicle hold disjoint, rising ``seq``
ranges. With several replicas a sample the vehicle sent to two of them may
be stored twice (docs/live.md, "Several replicas"); reads go through
:func:`distinct_samples`, which gives each ``seq`` once. Indexes
``(vehicle_id, max_seq)``, ``(vehicle_id, end)``, ``(end)``; no unique index,
no ``$group``, no update (see docs/storage.md).

``telemetry_marks``: one document per vehicle (``_id`` its id), ``seq`` the highest
of its buckets that retention dropped (raised with ``$max`` before they go). The
highest ``seq`` a vehicle has stored outlives its telemetry: a sample at or below it
is still a duplicate, and ``start_instance``'s ``last_seq`` still says where to go on.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterable, Iterator, Mapping
from datetime import UTC, datetime
from typing import Any

import bson
import orjson

from server.storage.backends import Doc, Rejected, Store

COLLECTION = "telemetry"
MARKS = "telemetry_marks"
#: Buckets retention reads and drops at a time.
_DROP_BATCH = 1000
_META = {"samples": 0}
_CODEC: bson.CodecOptions[Any] = bson.CodecOptions(tz_aware=True)


#: The binary subtype of samples packed as JSON text (one of BSON's user-defined ones).
PACKED_JSON = 0x80
_from_iso = datetime.fromisoformat


def pack(samples: list[Doc]) -> bson.Binary:
    """The samples as one binary of JSON text; :class:`Rejected` when it cannot hold them
    (checked samples always fit: what JSON and the store cannot hold is refused first)."""
    try:
        return bson.Binary(orjson.dumps(samples), PACKED_JSON)
    except orjson.JSONEncodeError as exc:
        raise Rejected(f"{type(exc).__name__}: {exc}") from exc


def samples_of(bucket: Mapping[str, Any]) -> list[Doc]:
    """A bucket's samples, in ``seq`` order: packed as JSON, as BSON (buckets stored
    before), or a list (older stores)."""
    raw = bucket["samples"]
    if isinstance(raw, bytes):
        if getattr(raw, "subtype", 0) == PACKED_JSON:
            samples: list[Doc] = orjson.loads(memoryview(raw))  # Binary: a bytes subclass
            for sample in samples:
                sample["ts"] = _from_iso(sample["ts"])
            return samples
        samples = bson.decode(raw, _CODEC)["s"]
        return samples
    return list(raw)


def distinct_samples(buckets: Iterable[Mapping[str, Any]]) -> Iterator[Doc]:
    """The samples of ``buckets`` in ``seq`` order, each ``seq`` once.

    Buckets whose ``seq`` ranges overlap no other (all of them, on one replica)
    are read as they are, one after the other. Overlapping ones are merged by
    ``seq`` and, of two copies of one ``seq``, the copy in the bucket inserted
    first (lowest ``_id``: an ObjectId begins with its insert time) is kept.
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
    runs = [samples_of(b) for b in sorted(group, key=lambda b: str(b.get("_id", "")))]
    last = None
    for sample in heapq.merge(*runs, key=lambda s: int(s["seq"])):
        if sample["seq"] != last:
            last = sample["seq"]
            yield sample


class TelemetryRepo:
    def __init__(self, store: Store) -> None:
        self.coll = store[COLLECTION]
        self.marks = store[MARKS]

    async def ensure_indexes(self) -> None:
        await self.coll.create_index([("vehicle_id", 1), ("max_seq", 1)])
        await self.coll.create_index([("vehicle_id", 1), ("end", 1)])
        await self.coll.create_index([("end", 1)])

    # ---- writes -------------------------------------------------------------
    @staticmethod
    def make_bucket(vehicle_id: str, samples: list[Doc], stored: datetime | None = None) -> Doc:
        """A bucket document for ``samples`` (stored form, ``seq`` order, not empty);
        :class:`Rejected` when BSON cannot hold them. ``stored``: when the server stores
        it (retention counts from it too: see :meth:`drop_ended_before`)."""
        packed = pack(samples)
        times = [s["ts"] for s in samples]
        extra = {"stored": stored} if stored is not None else {}
        return {
            **extra,
            "vehicle_id": vehicle_id,
            "start": min(times),
            "end": max(times),
            "min_seq": samples[0]["seq"],
            "max_seq": samples[-1]["seq"],
            "n": len(samples),
            "bytes": len(packed),
            "samples": packed,
        }

    async def insert(self, bucket: Doc) -> None:
        await self.coll.insert(bucket)

    async def insert_many(self, buckets: list[Doc]) -> None:
        """Bulk load (benchmarks, imports): one driver call."""
        await self.coll.insert_many(buckets)

    async def drop_ended_before(self, cutoff: datetime) -> int:
        """Retention: drop every bucket whose newest sample is older than ``cutoff`` and
        that was stored before it too (samples dated long ago by a vehicle's clock, or
        uploaded from an outbox days later, are kept for the retention from their
        arrival: acknowledged as durable, they are not dropped a minute later), each
        vehicle's highest ``seq`` among them kept in its mark first (by id: a bucket
        written meanwhile is left for the next pass, never dropped unmarked)."""
        dropped = 0
        stored_before = [{"stored": {"$lt": cutoff}}, {"stored": {"$exists": False}}]
        while True:
            found = await self.coll.find(
                {"end": {"$lt": cutoff}, "$or": stored_before},
                projection={"vehicle_id": 1, "max_seq": 1},
                limit=_DROP_BATCH,
            )
            if not found:
                return dropped
            highest: dict[str, int] = {}
            for bucket in found:
                vehicle = bucket["vehicle_id"]
                highest[vehicle] = max(highest.get(vehicle, -1), int(bucket["max_seq"]))
            for vehicle, seq in highest.items():
                await self.marks.update({"_id": vehicle}, max={"seq": seq}, upsert=True)
            dropped += await self.coll.delete({"_id": {"$in": [b["_id"] for b in found]}})
            if len(found) < _DROP_BATCH:
                return dropped

    # ---- reads --------------------------------------------------------------
    async def max_seq(self, vehicle_id: str) -> int:
        """Highest ``seq`` the vehicle has stored, its dropped buckets' too; -1 when none."""
        doc = await self.coll.find(
            {"vehicle_id": vehicle_id}, sort=[("max_seq", -1)], limit=1, projection=_META
        )
        mark = await self.marks.get(vehicle_id)
        kept = int(doc[0]["max_seq"]) if doc else -1
        return max(kept, int(mark["seq"]) if mark else -1)

    async def latest_sample(self, vehicle_id: str, before: datetime | None = None) -> Doc | None:
        """The stored sample with the greatest ``ts`` (it is in the bucket ending last; of
        two such buckets, copies of one sample, the one inserted first). With ``before``:
        the greatest ``ts`` not past it (a sample dated years ahead by a clock glitch is no
        position), looked for in the four buckets ending last that begin before it."""
        if before is None:
            last = await self.coll.find(
                {"vehicle_id": vehicle_id}, sort=[("end", -1)], limit=1, projection=_META
            )
            if not last:
                return None
            ending = await self.coll.find({"vehicle_id": vehicle_id, "end": last[0]["end"]})
            first = min(ending, key=lambda b: str(b["_id"]))
            return max(samples_of(first), key=lambda s: (s["ts"], s["seq"]))
        near = await self.coll.find(
            {"vehicle_id": vehicle_id, "start": {"$lte": before}}, sort=[("end", -1)], limit=4
        )
        held = [s for b in near for s in samples_of(b) if _aware(s["ts"]) <= before]
        return max(held, key=lambda s: (s["ts"], s["seq"])) if held else None

    async def in_window(self, vehicle_id: str, start: datetime, end: datetime) -> list[Doc]:
        """Buckets that may hold samples with ``start <= ts < end``."""
        return await self.coll.find(
            {"vehicle_id": vehicle_id, "end": {"$gte": start}, "start": {"$lt": end}}
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
        """Up to ``limit`` buckets holding samples with ``seq > after_seq``, in ``max_seq``
        order (read them with :func:`distinct_samples`). With ``start``/``end``, only
        buckets that may hold samples with ``start <= ts < end``."""
        flt: Doc = {"vehicle_id": vehicle_id, "max_seq": {"$gt": after_seq}}
        if start is not None:
            flt["end"] = {"$gte": start}
        if end is not None:
            flt["start"] = {"$lt": end}
        return await self.coll.find(flt, sort=[("max_seq", 1)], limit=limit)


def _aware(ts: datetime) -> datetime:
    """A stored time as UTC (a store's driver may hand back a naive one)."""
    return ts if ts.tzinfo is not None else ts.replace(tzinfo=UTC)
