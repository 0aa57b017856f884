"""Telemetry's writer: the open buckets inserted into the store and made durable (the
ingest that fills them: :class:`server.services.telemetry.TelemetryService`, one).

- The open bucket is inserted whole when it holds ``bucket_samples`` or
  ``bucket_max_bytes`` (in the ingest call) or is ``bucket_max_age_s`` old
  (by :meth:`TelemetryWriter.writer_step`).
- ``durable_through_seq`` is the highest ``seq`` in a bucket that survives a
  crash: on MongoDB once its insert is acknowledged with the configured write
  concern (default majority, journaled); on the embedded store once a
  ``store.flush()`` begun after its insert has completed.
- The writer handles one vehicle's bucket at a time: a bucket the store
  refuses is split, the samples it cannot hold are kept aside
  (:mod:`server.services.dead_letters`), the rest is written, and the other
  vehicles' buckets go on regardless.
"""

from __future__ import annotations

import asyncio
import heapq
import logging
import time
from dataclasses import dataclass, field

import bson

from server.domain.clock import Clock
from server.errors import Unavailable
from server.services.dead_letters import DeadLetters
from server.services.pacing import Pacer, period_of
from server.settings import Settings
from server.storage.backends import ENCODE_ERRORS, Doc, Rejected, Store
from server.storage.telemetry import TelemetryRepo

log = logging.getLogger("fleet.telemetry")


@dataclass(slots=True)
class VehicleTelemetry:
    """What the service holds of one vehicle's telemetry: its marks and its open bucket."""

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


#: BSON size of a sample's fixed fields (seq, ts, position, depth, heading, speed, battery).
SAMPLE_BYTES = 160


def sample_size(doc: Doc) -> int:
    """The BSON size of a stored sample, near enough (exact for its ``data``)."""
    data = doc.get("data")
    if not data:
        return SAMPLE_BYTES
    try:
        return SAMPLE_BYTES + len(bson.encode(data))
    except ENCODE_ERRORS:
        return SAMPLE_BYTES  # refused when its bucket is written, and kept aside then


class TelemetryWriter:
    """The store side of the telemetry service: its vehicles' open buckets written one
    vehicle at a time, and their marks moved when what was written is durable. The
    service (:class:`~server.services.telemetry.TelemetryService`) sets what it is given."""

    settings: Settings
    store: Store
    repo: TelemetryRepo
    dead_letters: DeadLetters
    clock: Clock

    def __init__(self) -> None:
        self._vehicles: dict[str, VehicleTelemetry] = {}
        #: ``(due_at, vehicle_id)`` of each open bucket, a heap: the writer takes the due
        #: ones from its top rather than looking at every vehicle each pass. An entry
        #: whose vehicle's bucket has been written since is passed over.
        self._opened: list[tuple[float, str]] = []
        #: Vehicles with buckets written but not yet flushed (embedded store).
        self._unflushed: set[str] = set()

    def _open(self, vehicle_id: str, state: VehicleTelemetry) -> None:
        """The vehicle's open bucket starts now (its first pending sample came)."""
        if not state.max_age_s:  # each vehicle its own: buckets opened together drift apart
            state.max_age_s = period_of(vehicle_id, self.settings.bucket_max_age_s)
        state.opened_at = opened = time.monotonic()
        state.due_at = due = opened + state.max_age_s
        heapq.heappush(self._opened, (due, vehicle_id))

    def _written(self, vehicle_id: str, state: VehicleTelemetry, mark: int) -> None:
        """A bucket through ``mark`` is in the store: durable now, or at the next flush."""
        if self.store.durable_on_write:
            state.durable = max(state.durable, mark)
        else:
            state.unflushed.append(mark)
            self._unflushed.add(vehicle_id)

    def _full(self, state: VehicleTelemetry) -> bool:
        return (
            len(state.pending) >= self.settings.bucket_samples
            or state.pending_bytes >= self.settings.bucket_max_bytes
        )

    def _chunk(self, state: VehicleTelemetry) -> tuple[list[Doc], int]:
        """The oldest pending samples that make one bucket (by count and bytes)."""
        cap, max_bytes = self.settings.bucket_samples, self.settings.bucket_max_bytes
        if len(state.pending) <= cap and state.pending_bytes <= max_bytes:
            return state.pending[:], state.pending_bytes  # all of it: the common case
        size = 0
        for i, doc in enumerate(state.pending[:cap]):
            grown = size + sample_size(doc)
            if i and grown > max_bytes:
                return state.pending[:i], size
            size = grown
        return state.pending[:cap], size

    async def _write_bucket(
        self, vehicle_id: str, state: VehicleTelemetry, *, best_effort: bool = False
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

    async def _write_vehicle(
        self, vehicle_id: str, state: VehicleTelemetry, everything: bool
    ) -> int:
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
