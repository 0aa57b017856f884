"""Telemetry: idempotent ingest, bucketed insert-only storage, durability marks (the
views: :mod:`server.services.telemetry_views`).

Per vehicle the service keeps the ``seq`` high-water mark, the samples not
yet written (the open bucket), the latest position and the durable mark.

- A sample at or below the high-water mark is a duplicate: counted, not
  stored. Batches of one vehicle run one at a time (a lock per vehicle).
- The open bucket is inserted whole when it holds ``bucket_samples`` or
  ``bucket_max_bytes`` (in the ingest call) or is ``bucket_max_age_s`` old
  (by :meth:`run_writer`).
- ``acked_through_seq`` is the high-water mark (in memory or stored).
  ``durable_through_seq`` is the highest ``seq`` in a bucket that survives a
  crash: on MongoDB once its insert is acknowledged with the configured write
  concern (default majority, journaled); on the embedded store once a
  ``store.flush()`` begun after its insert has completed.
- The writer handles one vehicle's bucket at a time: a bucket the store
  refuses is split, the samples it cannot hold are kept aside
  (:mod:`server.services.dead_letters`), the rest is written, and the other
  vehicles' buckets go on regardless.
- The latest position is the sample with the greatest ``ts``. A sample older
  than the latest position, or older than ``offline_after_s`` when it
  arrives, is flagged ``replayed`` (it came late, from an outbox).
- Reads show each ``seq`` once (:func:`distinct_samples`): with several
  replicas a vehicle that moves between them may have a sample stored twice.
  On ``start_instance`` the high-water mark is read from the store again
  (the vehicle may have sent samples through another replica since).
- -1 stands for "no sample" in ``seq`` marks (a vehicle's first ``seq`` may be 0).
"""

from __future__ import annotations

import asyncio
import heapq
import logging
import time
from dataclasses import dataclass, field
from datetime import datetime, timedelta

import bson
from pydantic import TypeAdapter

from fleet_protocol import Sample, utcnow
from server.domain.clock import Clock
from server.errors import Unavailable
from server.services.dead_letters import DeadLetters
from server.services.pacing import Pacer, period_of
from server.services.telemetry_views import TelemetryViews
from server.settings import Settings
from server.storage.backends import ENCODE_ERRORS, Doc, Rejected, Store
from server.storage.telemetry import TelemetryRepo

log = logging.getLogger("fleet.telemetry")

#: Open buckets kept in memory per vehicle while the store refuses writes.
MAX_PENDING_BUCKETS = 50


@dataclass(slots=True)
class IngestResult:
    accepted: int
    duplicates: int
    acked_through_seq: int
    durable_through_seq: int
    #: The vehicle's new latest position when this batch moved it, else None.
    latest: Sample | None
    #: The accepted samples, in the order received, and whether each came late.
    stored: list[Sample] = field(default_factory=list)
    replayed: list[bool] = field(default_factory=list)
    #: ``latest`` in its stored form (a dict shared with the open bucket: read, never change).
    latest_doc: Doc | None = None


@dataclass(slots=True)
class _Vehicle:
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    loaded: bool = False
    high: int = -1
    durable: int = -1
    pending: list[Doc] = field(default_factory=list)
    pending_bytes: int = 0  # estimated BSON size of ``pending``
    opened_at: float = 0.0  # monotonic time of the open bucket's first sample
    due_at: float = 0.0  # monotonic time it is written at the latest (its age is up)
    max_age_s: float = 0.0  # this vehicle's bucket age (period_of bucket_max_age_s)
    unflushed: list[int] = field(default_factory=list)  # max_seq of buckets awaiting a flush
    #: The latest sample in its stored form (a dict, shared with the open bucket: read,
    #: never changed). Not the model: one per vehicle, replaced every second, each
    #: would outlive a young collection and be scanned by the next one.
    latest: Doc | None = None


#: How far ahead of the server's clock a sample's ``ts`` may be and still become the
#: vehicle's latest position (its clock a little fast). Past it (a GPS or clock glitch:
#: 2099), the sample is stored as sent but would otherwise hold the position for years.
_AHEAD = timedelta(minutes=5)

#: BSON size of a sample's fixed fields (seq, ts, position, depth, heading, speed, battery).
_SAMPLE_BYTES = 160


#: Samples in their stored form (each one's ``model_dump(exclude_none=True)``), a batch in
#: one call of the serializer rather than one call per sample.
_STORED: TypeAdapter[list[Sample]] = TypeAdapter(list[Sample])


def _stored(samples: list[Sample]) -> list[Doc]:
    docs: list[Doc] = _STORED.dump_python(samples, exclude_none=True)
    return docs


def _size(doc: Doc) -> int:
    """The BSON size of a stored sample, near enough (exact for its ``data``)."""
    data = doc.get("data")
    if not data:
        return _SAMPLE_BYTES
    try:
        return _SAMPLE_BYTES + len(bson.encode(data))
    except ENCODE_ERRORS:
        return _SAMPLE_BYTES  # refused when its bucket is written, and kept aside then


def _sample(doc: Doc) -> Sample:
    return Sample.from_stored(doc)


class TelemetryService(TelemetryViews):
    def __init__(
        self,
        settings: Settings,
        store: Store,
        repo: TelemetryRepo,
        dead_letters: DeadLetters,
        clock: Clock = utcnow,
    ) -> None:
        self.settings = settings
        self.store = store
        self.repo = repo
        self.dead_letters = dead_letters
        self.clock = clock
        self._vehicles: dict[str, _Vehicle] = {}
        #: ``(due_at, vehicle_id)`` of each open bucket, a heap: the writer takes the due
        #: ones from its top rather than looking at every vehicle each pass. An entry
        #: whose vehicle's bucket has been written since is passed over.
        self._opened: list[tuple[float, str]] = []
        #: Vehicles with buckets written but not yet flushed (embedded store).
        self._unflushed: set[str] = set()
        self._offline_after = timedelta(seconds=settings.offline_after_s)

    async def load(self) -> None:
        await self.repo.ensure_indexes()

    # ---- ingest -------------------------------------------------------------
    def _state(self, vehicle_id: str) -> _Vehicle:
        state = self._vehicles.get(vehicle_id)
        if state is None:
            state = self._vehicles[vehicle_id] = _Vehicle()
        return state

    async def _load(self, vehicle_id: str, state: _Vehicle, *, again: bool = False) -> None:
        """High-water mark and latest position from the store, once per vehicle or ``again``
        (under its lock). Each moves forward only."""
        if state.loaded and not again:
            return
        high = await self.repo.max_seq(vehicle_id)
        latest = await self.repo.latest_sample(vehicle_id, before=self.clock() + _AHEAD)
        state.high = max(state.high, high)
        state.durable = max(state.durable, high)  # what was stored before is durable
        if latest is not None and (state.latest is None or latest["ts"] > state.latest["ts"]):
            state.latest = latest
        state.loaded = True

    async def ingest(
        self, vehicle_id: str, instance_id: str, samples: list[Sample]
    ) -> IngestResult:
        if self.takes_now(vehicle_id, len(samples)):
            return self.ingest_now(vehicle_id, samples)
        state = self._vehicles.get(vehicle_id) or self._state(vehicle_id)
        cap = self.settings.bucket_samples
        async with state.lock:
            await self._load(vehicle_id, state)
            if samples and len(state.pending) >= cap * MAX_PENDING_BUCKETS:
                raise Unavailable("telemetry cannot be stored now; send it again shortly")
            result = self._accept(vehicle_id, state, samples)
            while self._full(state):
                if not await self._write_bucket(vehicle_id, state, best_effort=True):
                    break
            result.acked_through_seq = state.high
            result.durable_through_seq = state.durable
            return result

    def _open(self, vehicle_id: str, state: _Vehicle) -> None:
        """The vehicle's open bucket starts now (its first pending sample came)."""
        if not state.max_age_s:  # each vehicle its own: buckets opened together drift apart
            state.max_age_s = period_of(vehicle_id, self.settings.bucket_max_age_s)
        state.opened_at = opened = time.monotonic()
        state.due_at = due = opened + state.max_age_s
        heapq.heappush(self._opened, (due, vehicle_id))

    def _written(self, vehicle_id: str, state: _Vehicle, mark: int) -> None:
        """A bucket through ``mark`` is in the store: durable now, or at the next flush."""
        if self.store.durable_on_write:
            state.durable = max(state.durable, mark)
        else:
            state.unflushed.append(mark)
            self._unflushed.add(vehicle_id)

    def takes_now(self, vehicle_id: str, count: int) -> bool:
        """Whether ``count`` samples of the vehicle can be taken without waiting: the
        vehicle known, its open bucket not full with them, no write of its own under way
        (the common case; it awaits nothing, so no lock is needed)."""
        state = self._vehicles.get(vehicle_id)
        return (
            state is not None
            and state.loaded
            and not state.lock.locked()
            and len(state.pending) + count < self.settings.bucket_samples
            and state.pending_bytes < self.settings.bucket_max_bytes
        )

    def ingest_now(self, vehicle_id: str, samples: list[Sample]) -> IngestResult:
        """:meth:`ingest` within this call; only when :meth:`takes_now` said so."""
        return self._accept(vehicle_id, self._vehicles[vehicle_id], samples)

    def _accept(self, vehicle_id: str, state: _Vehicle, samples: list[Sample]) -> IngestResult:
        """Take the new samples into the open bucket (synchronous: the caller holds the turn)."""
        result = IngestResult(0, 0, -1, -1, None)
        high = state.high
        stored = result.stored
        for sample in samples:
            if sample.seq <= high:
                result.duplicates += 1
                continue
            high = sample.seq
            stored.append(sample)
        state.high = high
        result.accepted = len(stored)
        result.acked_through_seq = high
        result.durable_through_seq = state.durable
        if not stored:
            return result
        # The same instant in the samples' own tzinfo: two datetimes of one tzinfo are
        # compared without a call to either's utcoffset (one per sample saved).
        now = self.clock()
        stale_before = now - self._offline_after
        ahead = now + _AHEAD  # a sample past it is stored, never the latest position
        if (tz := stored[0].ts.tzinfo) is not None:
            stale_before = stale_before.astimezone(tz)
            ahead = ahead.astimezone(tz)
        pending, replayed = state.pending, result.replayed
        if not pending:
            self._open(vehicle_id, state)
        latest = state.latest
        latest_ts = latest["ts"] if latest is not None else None
        added = 0
        for sample, doc in zip(stored, _stored(stored), strict=True):
            pending.append(doc)
            added += _size(doc) if "data" in doc else _SAMPLE_BYTES
            ts = sample.ts
            replayed.append((latest_ts is not None and ts < latest_ts) or ts < stale_before)
            if (latest_ts is None or ts >= latest_ts) and ts <= ahead:
                latest, latest_ts = doc, ts
                result.latest, result.latest_doc = sample, doc
        state.pending_bytes += added
        state.latest = latest
        return result

    def _full(self, state: _Vehicle) -> bool:
        return (
            len(state.pending) >= self.settings.bucket_samples
            or state.pending_bytes >= self.settings.bucket_max_bytes
        )

    def _chunk(self, state: _Vehicle) -> tuple[list[Doc], int]:
        """The oldest pending samples that make one bucket (by count and bytes)."""
        cap, max_bytes = self.settings.bucket_samples, self.settings.bucket_max_bytes
        if len(state.pending) <= cap and state.pending_bytes <= max_bytes:
            return state.pending[:], state.pending_bytes  # all of it: the common case
        size = 0
        for i, doc in enumerate(state.pending[:cap]):
            grown = size + _size(doc)
            if i and grown > max_bytes:
                return state.pending[:i], size
            size = grown
        return state.pending[:cap], size

    async def _write_bucket(
        self, vehicle_id: str, state: _Vehicle, *, best_effort: bool = False
    ) -> bool:
        """Insert the oldest pending samples as one bucket (under the vehicle's lock).

        A bucket the store refuses is written sample by sample: what the store
        cannot hold is kept aside, the rest is stored. Unavailable: the samples
        stay pending (raised, or False with ``best_effort``).
        """
        chunk, size = self._chunk(state)
        try:
            await self.repo.insert(self.repo.make_bucket(vehicle_id, chunk, self.clock()))
        except Rejected as exc:
            try:
                await self._write_apart(vehicle_id, chunk, exc)
            except Unavailable:
                if not best_effort:
                    raise
                return False
        except Unavailable:
            if not best_effort:
                raise
            log.warning("telemetry of %s kept in memory: the store refused the write", vehicle_id)
            return False
        del state.pending[: len(chunk)]
        state.pending_bytes = max(0, state.pending_bytes - size)
        if state.pending:
            self._open(vehicle_id, state)
        self._written(vehicle_id, state, int(chunk[-1]["seq"]))
        return True

    async def _write_apart(self, vehicle_id: str, chunk: list[Doc], error: Exception) -> None:
        """A bucket the store refused: its samples one by one, those refused set aside."""
        log.error("telemetry of %s: a bucket was refused (%s); writing it apart", vehicle_id, error)
        good: list[Doc] = []
        for doc in chunk:
            try:
                self.repo.make_bucket(vehicle_id, [doc], self.clock())
            except Rejected as exc:
                await self._set_aside(vehicle_id, doc, exc)
                continue
            good.append(doc)
        if not good:
            return
        try:
            await self.repo.insert(self.repo.make_bucket(vehicle_id, good, self.clock()))
            return
        except Rejected:
            pass  # the store itself refuses something in it: one bucket per sample
        for doc in good:
            try:
                await self.repo.insert(self.repo.make_bucket(vehicle_id, [doc], self.clock()))
            except Rejected as exc:
                await self._set_aside(vehicle_id, doc, exc)

    async def _set_aside(self, vehicle_id: str, doc: Doc, error: Exception) -> None:
        record_id = f"{vehicle_id}/{doc.get('seq')}"
        if not await self.dead_letters.set_aside("telemetry", record_id, error, doc):
            raise Unavailable("a refused sample could not be kept aside; it stays pending")

    async def last_seq(self, vehicle_id: str) -> int:
        """The vehicle's highest ``seq`` the server has (-1: none), for ``start_instance``.

        With several replicas it is read from the store again: since this replica
        read it the vehicle may have sent samples through another one.
        """
        state = self._state(vehicle_id)
        async with state.lock:
            await self._load(vehicle_id, state, again=True)
            return state.high

    async def latest(self, vehicle_id: str) -> Sample | None:
        state = self._state(vehicle_id)
        async with state.lock:
            await self._load(vehicle_id, state)
            return _sample(state.latest) if state.latest is not None else None

    def durable_through_seq(self, vehicle_id: str) -> int:
        state = self._vehicles.get(vehicle_id)
        return state.durable if state is not None else -1

    # ---- writer -------------------------------------------------------------
    async def write_due(self, *, everything: bool = False) -> int:
        """Insert every open bucket whose age is up (every open one with ``everything``);
        a vehicle's bucket age is ``bucket_max_age_s`` shortened by up to a quarter
        (:func:`period_of`), so that buckets opened together drift apart. One vehicle at
        a time: one that fails does not hold up the others. A full bucket is written by
        the ingest call that fills it; one the store could not take then is written here
        once its age is up."""
        if everything:
            due = [(0.0, v) for v, state in self._vehicles.items() if state.pending]
        else:
            due = self._aged(time.monotonic())
        written = 0
        pacer = Pacer()
        for i, (_, vehicle_id) in enumerate(due):
            state = self._vehicles.get(vehicle_id)
            if state is None or not state.pending:
                continue
            try:
                written += await self._write_vehicle(vehicle_id, state, everything)
            except Unavailable as exc:
                self.dead_letters.failed("telemetry", exc)
                if not everything:  # the store is away: the next pass tries these again
                    for entry in due[i:]:
                        heapq.heappush(self._opened, entry)
                break
            except Exception as exc:
                # Not the store, not a sample BSON refuses: keep the bucket aside, go on.
                async with state.lock:
                    chunk, size = self._chunk(state)
                    if await self.dead_letters.set_aside("telemetry", vehicle_id, exc, chunk):
                        del state.pending[: len(chunk)]
                        state.pending_bytes = max(0, state.pending_bytes - size)
                        self._written(vehicle_id, state, int(chunk[-1]["seq"]))
                    if state.pending:
                        self._open(vehicle_id, state)
            await pacer.step()  # buckets that opened together age out together
        return written

    def _aged(self, now: float) -> list[tuple[float, str]]:
        """The open buckets due by ``now``, taken off the heap (entries of buckets written
        since, whose vehicle opened a newer one, are dropped)."""
        heap, vehicles, out = self._opened, self._vehicles, []
        while heap and heap[0][0] <= now:
            due, vehicle_id = entry = heapq.heappop(heap)
            state = vehicles.get(vehicle_id)
            if state is not None and state.pending and state.due_at == due:
                out.append(entry)
        return out

    async def _write_vehicle(self, vehicle_id: str, state: _Vehicle, everything: bool) -> int:
        written = 0
        async with state.lock:
            while state.pending and (
                everything or self._full(state) or time.monotonic() >= state.due_at
            ):
                await self._write_bucket(vehicle_id, state)
                written += 1
        return written

    async def make_durable(self) -> bool:
        """Embedded store: flush the journal, then move the durable marks. True if they moved."""
        if self.store.durable_on_write:
            return False
        vehicles = self._vehicles
        marks = {}
        for vehicle_id in self._unflushed:
            state = vehicles.get(vehicle_id)
            if state is not None and state.unflushed:
                marks[vehicle_id] = (len(state.unflushed), state.unflushed[-1])
        self._unflushed.clear()  # a bucket written during the flush adds its vehicle again
        if not marks:
            return False
        try:
            await self.store.flush()  # everything recorded before this call is on disk after it
        except BaseException:
            self._unflushed.update(marks)  # the next pass tries again
            raise
        for vehicle_id, (count, mark) in marks.items():
            state = self._vehicles[vehicle_id]
            state.durable = max(state.durable, mark)
            del state.unflushed[:count]
            if state.unflushed:  # written while the flush ran: the next flush moves it
                self._unflushed.add(vehicle_id)
        return True

    async def drop_before(self, before: datetime) -> int:
        """Retention: drop the buckets whose newest sample is older than ``before``."""
        dropped = await self.repo.drop_ended_before(before)
        if dropped:
            log.info("telemetry retention: %d buckets older than %s dropped", dropped, before)
        return dropped

    def writer_tick_s(self) -> float:
        return min(max(self.settings.bucket_max_age_s / 4, 0.05), 0.5)

    async def writer_step(self) -> None:
        """One pass of the writer: aged buckets inserted, then made durable."""
        await self.write_due()
        try:
            await self.make_durable()
        except Exception as exc:  # the journal's disk: the marks wait for the next pass
            self.dead_letters.failed("journal", exc)

    async def flush_all(self) -> None:
        """Shutdown: write every open bucket and make it durable."""
        await self.write_due(everything=True)
        await self.make_durable()

    # ---- views --------------------------------------------------------------
    def _tail(self, vehicle_id: str) -> list[Doc]:
        """The samples not yet in a bucket (snapshot, taken before reading buckets)."""
        state = self._vehicles.get(vehicle_id)
        return list(state.pending) if state is not None else []
