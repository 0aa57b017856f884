"""Telemetry: idempotent ingest into per-vehicle open buckets (their writer, bucketed
insert-only storage and durability marks: :mod:`server.services.telemetry_writer`; the
views: :mod:`server.services.telemetry_views`).

Per vehicle the service keeps the ``seq`` high-water mark, the samples not
yet written (the open bucket), the latest position and the durable mark.

- A sample at or below the high-water mark is a duplicate: counted, not
  stored. Batches of one vehicle run one at a time (a lock per vehicle).
- ``acked_through_seq`` is the high-water mark (in memory or stored);
  ``durable_through_seq`` is the writer's durable mark.
- The latest position is the sample with the greatest ``ts``, but never one dated
  more than five minutes ahead (a clock glitch). A sample older than the latest
  position, or older than ``offline_after_s`` when it arrives, is flagged
  ``replayed`` (it came late, from an outbox). The latest position, when it came in
  time, is the batch's ``current`` sample: the only one anything judging "now" reads.
- Reads show each ``seq`` once (:func:`distinct_samples`): with several
  replicas a vehicle that moves between them may have a sample stored twice.
  On ``start_instance`` the high-water mark is read from the store again
  (the vehicle may have sent samples through another replica since).
- -1 stands for "no sample" in ``seq`` marks (a vehicle's first ``seq`` may be 0).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime, timedelta

from pydantic import TypeAdapter

from fleet_protocol import Sample, utcnow
from server.domain.clock import Clock
from server.errors import Unavailable
from server.services.dead_letters import DeadLetters
from server.services.telemetry_views import TelemetryViews
from server.services.telemetry_writer import (
    SAMPLE_BYTES,
    TelemetryWriter,
    VehicleTelemetry,
    sample_size,
)
from server.settings import Settings
from server.storage.backends import Doc, Store
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
    #: The vehicle's new latest position when this batch moved it, else None (stored
    #: form, a dict shared with the open bucket: read, never change).
    latest: Doc | None
    #: The accepted samples in their stored form, in the order received, and whether
    #: each came late.
    stored: list[Doc] = field(default_factory=list)
    replayed: list[bool] = field(default_factory=list)
    #: ``latest`` when it also came in time (not late): what the vehicle reports now, the
    #: one sample of the batch that the watch on zones and battery judges (None: none).
    current: Doc | None = None
    #: The latest ``ts`` a sample of the batch could have and become the position (by the
    #: vehicle's clock, in the samples' tzinfo); None when none was accepted.
    ahead_after: datetime | None = None


#: How far ahead of the server's clock a sample's ``ts`` may be and still become the
#: vehicle's latest position (its clock a little fast). Past it (a GPS or clock glitch:
#: 2099), the sample is stored as sent but would otherwise hold the position for years.
_AHEAD = timedelta(minutes=5)


#: Samples in their stored form (each one's ``model_dump(exclude_none=True)``), a batch in
#: one call of the serializer rather than one call per sample.
_STORED: TypeAdapter[list[Sample]] = TypeAdapter(list[Sample])


def stored_form(samples: Sequence[Sample | Doc]) -> list[Doc]:
    """The samples in their stored form: :class:`Sample` models serialized, samples read
    as plain dicts (``SampleDoc``, the request's own) kept, their nulls left out."""
    docs: list[Doc] = []
    for doc in samples:
        if type(doc) is not dict:
            break
        if None in doc.values():
            for name in [name for name, value in doc.items() if value is None]:
                del doc[name]
        docs.append(doc)
    else:
        return docs
    models = [s if isinstance(s, Sample) else Sample.model_validate(s) for s in samples]
    out: list[Doc] = _STORED.dump_python(models, exclude_none=True)
    return out


def _sample(doc: Doc) -> Sample:
    return Sample.from_stored(doc)


class TelemetryService(TelemetryWriter, TelemetryViews):
    """The telemetry of every vehicle (see the module); its open buckets are written by
    :class:`~server.services.telemetry_writer.TelemetryWriter`."""

    def __init__(
        self,
        settings: Settings,
        store: Store,
        repo: TelemetryRepo,
        dead_letters: DeadLetters,
        clock: Clock = utcnow,
    ) -> None:
        super().__init__()
        self.settings = settings
        self.store = store
        self.repo = repo
        self.dead_letters = dead_letters
        self.clock = clock
        self._offline_after = timedelta(seconds=settings.offline_after_s)

    async def load(self) -> None:
        await self.repo.ensure_indexes()

    # ---- ingest -------------------------------------------------------------
    def _state(self, vehicle_id: str) -> VehicleTelemetry:
        state = self._vehicles.get(vehicle_id)
        if state is None:
            state = self._vehicles[vehicle_id] = VehicleTelemetry()
        return state

    async def _load(self, vehicle_id: str, state: VehicleTelemetry, *, again: bool = False) -> None:
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
        self,
        vehicle_id: str,
        instance_id: str,
        samples: Sequence[Sample | Doc],
        clock_offset_s: float = 0.0,
        arrived: datetime | None = None,
    ) -> IngestResult:
        """Take the samples (duplicates counted, not stored): models, or plain dicts read
        as ``SampleDoc`` (taken as they are: the caller hands them over). ``clock_offset_s``: the
        server's clock minus the vehicle's, as the vehicle last said: its samples are
        dated by its clock, so whether one is stale or too far ahead is judged by the
        server's clock turned into the vehicle's. ``arrived``: the server's clock as the
        samples came (read now when not given)."""
        if self.takes_now(vehicle_id, len(samples)):
            return self.ingest_now(vehicle_id, samples, clock_offset_s, arrived)
        state = self._vehicles.get(vehicle_id) or self._state(vehicle_id)
        cap = self.settings.bucket_samples
        async with state.lock:
            await self._load(vehicle_id, state)
            if samples and len(state.pending) >= cap * MAX_PENDING_BUCKETS:
                raise Unavailable("telemetry cannot be stored now; send it again shortly")
            result = self._accept(vehicle_id, state, samples, clock_offset_s, arrived)
            while self._full(state):
                if not await self._write_bucket(vehicle_id, state, best_effort=True):
                    break
            result.acked_through_seq = state.high
            result.durable_through_seq = state.durable
            return result

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

    def ingest_now(
        self,
        vehicle_id: str,
        samples: Sequence[Sample | Doc],
        clock_offset_s: float = 0.0,
        arrived: datetime | None = None,
    ) -> IngestResult:
        """:meth:`ingest` within this call; only when :meth:`takes_now` said so."""
        state = self._vehicles[vehicle_id]
        return self._accept(vehicle_id, state, samples, clock_offset_s, arrived)

    def _accept(
        self,
        vehicle_id: str,
        state: VehicleTelemetry,
        samples: Sequence[Sample | Doc],
        clock_offset_s: float,
        arrived: datetime | None,
    ) -> IngestResult:
        """Take the new samples into the open bucket (synchronous: the caller holds the turn)."""
        docs = stored_form(samples)
        result = IngestResult(0, 0, state.high, state.durable, None)
        if not docs:
            return result
        # Now in the samples' own tzinfo (an offset of zero: Timestamp's): two datetimes of
        # one tzinfo are compared without a call to either's utcoffset.
        now = arrived if arrived is not None else self.clock()
        if (tz := docs[0]["ts"].tzinfo) is not None and tz is not now.tzinfo:
            same = tz.utcoffset(now) == now.utcoffset()  # then no arithmetic is needed
            now = now.replace(tzinfo=tz) if same else now.astimezone(tz)
        if clock_offset_s:  # now by the vehicle's clock, which dates its samples
            now -= timedelta(seconds=clock_offset_s)
        stale_before = now - self._offline_after
        ahead = now + _AHEAD  # a sample past it is stored, never the latest position
        stored, replayed, pending = result.stored, result.replayed, state.pending
        opened = bool(pending)
        high = state.high
        latest = state.latest
        latest_ts = latest["ts"] if latest is not None else None
        added = 0
        for doc in docs:  # one pass: most batches are all new, in order
            seq = doc["seq"]
            if seq <= high:
                result.duplicates += 1
                continue
            high = seq
            if not opened:
                self._open(vehicle_id, state)
                opened = True
            stored.append(doc)
            pending.append(doc)
            added += sample_size(doc) if "data" in doc else SAMPLE_BYTES
            ts = doc["ts"]
            late = (latest_ts is not None and ts < latest_ts) or ts < stale_before
            replayed.append(late)
            if (latest_ts is None or ts >= latest_ts) and ts <= ahead:
                latest, latest_ts = doc, ts
                result.latest = doc
                result.current = None if late else doc
        state.high = result.acked_through_seq = high
        result.accepted = len(stored)
        if stored:
            result.ahead_after = ahead
            state.pending_bytes += added
            state.latest = latest
        return result

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

    async def drop_before(self, before: datetime) -> int:
        """Retention: drop the buckets whose newest sample is older than ``before``."""
        dropped = await self.repo.drop_ended_before(before)
        if dropped:
            log.info("telemetry retention: %d buckets older than %s dropped", dropped, before)
        return dropped

    # ---- views --------------------------------------------------------------
    def _tail(self, vehicle_id: str) -> list[Doc]:
        """The samples not yet in a bucket (snapshot, taken before reading buckets)."""
        state = self._vehicles.get(vehicle_id)
        return list(state.pending) if state is not None else []
