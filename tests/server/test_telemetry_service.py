"""TelemetryService on each store (the embedded one and FerretDB, through the real
MongoDB driver): ingest, durability, restart, retention, views."""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import bson
import pytest

from fleet_protocol import Sample
from server.services.telemetry import TelemetryService
from server.settings import Settings
from server.storage import Store, open_store
from server.storage.telemetry import TelemetryRepo
from tests.factories import FakeClock, make_dead_letters
from tests.stores import StoreBackend

T0 = datetime(2026, 11, 22, 10, 0, 0, tzinfo=UTC)


def samples(seqs: range | list[int], *, t0: datetime = T0, **extra: Any) -> list[Sample]:
    """One sample per seq, one second apart (seq n at t0 + n s), on a slow diagonal."""
    return [
        Sample(
            seq=n, ts=t0 + timedelta(seconds=n), lat=43.9 + n * 1e-5, lon=15.4 + n * 1e-5, **extra
        )
        for n in seqs
    ]


class World:
    """A service on an embedded store at one snapshot path; ``restart`` reopens it."""

    def __init__(self, settings: Settings, clock: FakeClock) -> None:
        self.settings = settings
        self.clock = clock
        self.store: Store
        self.svc: TelemetryService

    async def open(self) -> TelemetryService:
        self.store = open_store(self.settings)
        await self.store.load()
        repo = TelemetryRepo(self.store)
        dead = make_dead_letters(self.store, self.clock)
        self.svc = TelemetryService(self.settings, self.store, repo, dead, self.clock)
        await self.svc.load()
        return self.svc

    async def restart(self) -> TelemetryService:
        await self.svc.flush_all()
        await self.store.close()
        return await self.open()

    async def crash(self) -> TelemetryService:
        """Reopen from disk without any shutdown work: only what was flushed survives."""
        return await self.open()


@pytest.fixture
async def world(tmp_path: Path, store_backend: StoreBackend) -> AsyncIterator[World]:
    settings = Settings(
        _env_file=None,
        snapshot_path=tmp_path / "store.snapshot",  # type: ignore[call-arg]
        bucket_samples=5,
        bucket_max_age_s=60,
        retention_s=3600,
        **store_backend.settings,
    )
    w = World(settings, FakeClock(T0 + timedelta(hours=1)))
    await w.open()
    yield w
    await w.store.close()


def seqs_of(docs: list[dict[str, Any]]) -> list[int]:
    return [d["seq"] for d in docs]


async def test_ingest_is_idempotent_by_seq(world: World) -> None:
    first = await world.svc.ingest("usv-1", "i1", samples(range(1, 11)))
    assert (first.accepted, first.duplicates, first.acked_through_seq) == (10, 0, 10)
    again = await world.svc.ingest("usv-1", "i1", samples(range(5, 13)))
    assert (again.accepted, again.duplicates, again.acked_through_seq) == (2, 6, 12)
    page, _ = await world.svc.page("usv-1", limit=100)
    assert seqs_of(page) == list(range(1, 13))


async def test_gaps_are_allowed_and_lower_seqs_are_duplicates(world: World) -> None:
    result = await world.svc.ingest("usv-1", "i1", samples([1, 5, 100, 50, 101]))
    assert (result.accepted, result.duplicates, result.acked_through_seq) == (4, 1, 101)
    assert [s["seq"] for s in result.stored] == [1, 5, 100, 101]
    assert await world.svc.last_seq("usv-1") == 101
    assert await world.svc.last_seq("usv-unknown") == -1


async def test_vehicles_are_numbered_apart(world: World) -> None:
    await world.svc.ingest("usv-1", "i1", samples(range(1, 4)))
    other = await world.svc.ingest("usv-2", "i2", samples(range(1, 4)))
    assert (other.accepted, other.duplicates) == (3, 0)


async def test_durable_only_after_a_write_the_store_makes_durable(world: World) -> None:
    result = await world.svc.ingest("usv-1", "i1", samples(range(1, 8)))  # one full bucket of 5
    if world.store.durable_on_write:  # MongoDB: acknowledged with majority and the journal
        assert (result.acked_through_seq, result.durable_through_seq) == (7, 5)
        assert await world.svc.make_durable() is False
    else:  # embedded: once the journal holding the bucket is flushed
        assert (result.acked_through_seq, result.durable_through_seq) == (7, -1)
        assert await world.svc.make_durable() is True
    assert world.svc.durable_through_seq("usv-1") == 5  # the open bucket (6, 7) is not stored
    assert await world.svc.write_due() == 0  # not old yet (bucket_max_age_s = 60)
    assert await world.svc.write_due(everything=True) == 1
    await world.svc.make_durable()
    later = await world.svc.ingest("usv-1", "i1", [])
    assert (later.acked_through_seq, later.durable_through_seq) == (7, 7)


async def test_what_was_durable_survives_a_crash(world: World) -> None:
    await world.svc.ingest("usv-1", "i1", samples(range(1, 6)))
    await world.svc.make_durable()
    assert world.svc.durable_through_seq("usv-1") == 5
    await world.svc.ingest("usv-1", "i1", samples(range(6, 11)))  # a bucket, not flushed
    durable = world.svc.durable_through_seq("usv-1")
    assert durable == (10 if world.store.durable_on_write else 5)
    svc = await world.crash()
    page, _ = await svc.page("usv-1", limit=100)
    assert seqs_of(page) == list(range(1, durable + 1))
    assert await svc.last_seq("usv-1") == durable


async def test_restart_keeps_every_sample_and_the_high_water_mark(world: World) -> None:
    await world.svc.ingest("usv-1", "i1", samples(range(1, 13)))
    await world.svc.ingest("usv-2", "i2", samples(range(1, 4)))
    svc = await world.restart()
    assert await svc.last_seq("usv-1") == 12
    assert await svc.last_seq("usv-2") == 3
    page, _ = await svc.page("usv-1", limit=100)
    assert seqs_of(page) == list(range(1, 13))
    again = await svc.ingest("usv-1", "i1", samples(range(10, 14)))
    assert (again.accepted, again.duplicates, again.durable_through_seq) == (1, 3, 12)
    latest = await svc.latest("usv-1")
    assert latest is not None and latest.seq == 13


async def stored_two_days_ago(world: World, seqs: range) -> None:
    """Samples of two days ago, stored then (full buckets: written as they come)."""
    now = world.clock.now
    world.clock.now = T0 - timedelta(days=2)
    await world.svc.ingest("usv-1", "i1", samples(seqs, t0=T0 - timedelta(days=2)))
    world.clock.now = now


async def test_retention_drops_old_buckets_for_good(world: World) -> None:
    await stored_two_days_ago(world, range(1, 11))
    await world.svc.ingest("usv-1", "i1", samples(range(11, 16)))
    await world.svc.make_durable()
    assert await world.svc.drop_before(T0 - timedelta(days=1)) == 2
    page, _ = await world.svc.page("usv-1", limit=100)
    assert seqs_of(page) == list(range(11, 16))
    svc = await world.restart()
    page, _ = await svc.page("usv-1", limit=100)
    assert seqs_of(page) == list(range(11, 16))
    assert await svc.drop_before(T0 - timedelta(days=1)) == 0


async def test_samples_dated_long_ago_are_kept_the_retention_from_their_arrival(
    world: World,
) -> None:
    """A vehicle's clock reset to 1970 (or an outbox uploaded a week late): its samples
    were acknowledged as durable, then dropped by the next retention pass, a minute on."""
    epoch = datetime(1970, 1, 1, tzinfo=UTC)
    result = await world.svc.ingest("usv-1", "i1", samples(range(1, 11), t0=epoch))
    assert result.accepted == 10
    await world.svc.make_durable()
    assert await world.svc.drop_before(world.clock.now - timedelta(hours=1)) == 0
    page, _ = await world.svc.page("usv-1", limit=100)
    assert seqs_of(page) == list(range(1, 11))
    later = world.clock.now + timedelta(seconds=1)  # the retention from their arrival passed
    assert await world.svc.drop_before(later) == 2
    page, _ = await world.svc.page("usv-1", limit=100)
    assert seqs_of(page) == []


async def test_the_highest_seq_outlives_the_buckets_retention_drops(world: World) -> None:
    """API.md: a seq at or below the vehicle's highest stored one is a duplicate, and
    start_instance's last_seq says where to go on: after retention dropped every bucket
    of a vehicle as well (its seq 1-5 again were stored as new, and a local copy keyed
    on seq kept the old ones)."""
    await stored_two_days_ago(world, range(1, 31))
    await world.svc.make_durable()
    assert await world.svc.drop_before(T0 - timedelta(days=1)) > 0
    page, _ = await world.svc.page("usv-1", limit=100)
    assert seqs_of(page) == []  # all of it dropped
    svc = await world.restart()
    assert await svc.last_seq("usv-1") == 30
    again = await svc.ingest("usv-1", "i1", samples(range(1, 6)))
    assert (again.accepted, again.duplicates, again.acked_through_seq) == (0, 5, 30)
    on = await svc.ingest("usv-1", "i1", samples(range(31, 33)))
    assert on.accepted == 2


async def test_latest_is_the_greatest_ts_and_late_samples_are_replayed(world: World) -> None:
    world.clock.now = T0 + timedelta(seconds=20)
    first = await world.svc.ingest("usv-1", "i1", samples(range(10, 13)))
    assert first.latest is not None and first.latest["seq"] == 12
    assert first.replayed == [False, False, False]
    # seq 13 carries an older ts: stored in place, the latest position stays.
    late = Sample(seq=13, ts=T0 + timedelta(seconds=3), lat=1.0, lon=2.0)
    result = await world.svc.ingest("usv-1", "i1", [late])
    assert (result.accepted, result.latest, result.replayed) == (1, None, [True])
    # From an outbox, long after: newer than the latest but older than offline_after_s.
    world.clock.now = T0 + timedelta(minutes=10)
    drained = await world.svc.ingest("usv-1", "i1", samples(range(14, 16)))
    assert drained.replayed == [True, True]
    assert drained.latest is not None and drained.latest["seq"] == 15


async def test_track_window_is_ts_ordered_from_inclusive_to_exclusive(world: World) -> None:
    await world.svc.ingest("usv-1", "i1", samples(range(1, 13)))  # two buckets + 2 in memory
    await world.svc.ingest("usv-2", "i2", samples(range(1, 13)))
    start, end = T0 + timedelta(seconds=3), T0 + timedelta(seconds=12)
    track = await world.svc.track("usv-1", start, end)
    assert [p["seq"] for p in track.points] == list(range(3, 12))
    assert [p["ts"] for p in track.points] == sorted(p["ts"] for p in track.points)
    assert (track.truncated, track.next_from) == (False, None)


async def test_track_pages_with_next_from(world: World) -> None:
    await world.svc.ingest("usv-1", "i1", samples(range(1, 24)))
    start, end = T0, T0 + timedelta(hours=1)
    seen: list[int] = []
    pages = 0
    while True:
        track = await world.svc.track("usv-1", start, end, cap=10)
        seen += [p["seq"] for p in track.points]
        pages += 1
        if not track.truncated:
            break
        assert track.next_from is not None
        start = track.next_from
    assert seen == list(range(1, 24)) and pages == 3


async def test_track_downsamples_to_max_points_keeping_the_ends(world: World) -> None:
    await world.svc.ingest("usv-1", "i1", samples(range(1, 41)))
    track = await world.svc.track("usv-1", T0, T0 + timedelta(hours=1), max_points=7)
    assert len(track.points) == 7
    assert (track.points[0]["seq"], track.points[-1]["seq"]) == (1, 40)


async def test_page_by_seq_across_buckets_and_memory(world: World) -> None:
    await world.svc.ingest("usv-1", "i1", samples(range(1, 24)))  # 4 buckets + 3 in memory
    got: list[int] = []
    after = -1
    while True:
        page, next_after = await world.svc.page("usv-1", after_seq=after, limit=6)
        got += seqs_of(page)
        if next_after is None:
            assert len(page) < 6
            break
        after = next_after
    assert got == list(range(1, 24))


async def test_page_filters_by_time(world: World) -> None:
    await world.svc.ingest("usv-1", "i1", samples(range(1, 24)))
    page, next_after = await world.svc.page(
        "usv-1", start=T0 + timedelta(seconds=7), end=T0 + timedelta(seconds=19), limit=100
    )
    assert (seqs_of(page), next_after) == (list(range(7, 19)), None)
    assert all(d["ts"].tzinfo is not None for d in page)


async def test_a_full_page_gives_the_last_seq(world: World) -> None:
    await world.svc.ingest("usv-1", "i1", samples(range(1, 11)))
    page, next_after = await world.svc.page("usv-1", after_seq=2, limit=8)
    assert (seqs_of(page), next_after) == (list(range(3, 11)), 10)
    page, next_after = await world.svc.page("usv-1", after_seq=10, limit=8)
    assert (page, next_after) == ([], None)


async def test_a_seq_stored_twice_is_read_once_the_first_copy(world: World) -> None:
    """Two replicas may both store a sample (docs/live.md, "Several replicas"); the repo
    insert stands for the other replica's late write of 98..103, then of 102..103 again."""
    await world.svc.ingest("usv-1", "i1", samples(range(1, 104)))  # 20 buckets + 3 in memory
    await world.svc.flush_all()
    for seqs, battery in ((range(98, 104), 11.0), (range(102, 104), 22.0)):
        copies = [s.model_dump(exclude_none=True) for s in samples(seqs, battery_pct=battery)]
        await world.svc.repo.insert(TelemetryRepo.make_bucket("usv-1", copies))
    every = list(range(1, 104))
    for limit in (1000, 7):
        got: list[dict[str, Any]] = []
        after: int | None = -1
        while after is not None:
            page, after = await world.svc.page("usv-1", after_seq=after, limit=limit)
            got += page
        assert seqs_of(got) == every, limit
        assert all("battery_pct" not in d for d in got), limit
    track = await world.svc.track("usv-1", T0, T0 + timedelta(hours=1))
    assert [p["seq"] for p in track.points] == every
    assert all("battery_pct" not in p for p in track.points)
    latest = await world.svc.repo.latest_sample("usv-1")
    assert latest is not None and (latest["seq"], latest.get("battery_pct")) == (103, None)


async def test_of_two_copies_the_one_stored_first_is_read(world: World) -> None:
    """The other replica (the repo insert) writes 3..7 before this one writes its own copies."""
    await world.svc.ingest("usv-1", "i1", samples(range(1, 3)))
    copies = [s.model_dump(exclude_none=True) for s in samples(range(3, 8), battery_pct=11.0)]
    await world.svc.repo.insert(TelemetryRepo.make_bucket("usv-1", copies))
    assert (await world.svc.ingest("usv-1", "i1", samples(range(3, 11)))).accepted == 8
    expected = [11.0 if 3 <= n <= 7 else None for n in range(1, 11)]
    page, _ = await world.svc.page("usv-1", limit=100)
    assert [d.get("battery_pct") for d in page] == expected
    track = await world.svc.track("usv-1", T0, T0 + timedelta(hours=1))
    assert [p.get("battery_pct") for p in track.points] == expected


async def test_the_writer_takes_the_buckets_that_aged_and_only_those(
    tmp_path: Path, store_backend: StoreBackend
) -> None:
    settings = Settings(
        _env_file=None,
        snapshot_path=tmp_path / "aged.snapshot",  # type: ignore[call-arg]
        bucket_samples=100,
        bucket_max_age_s=0.3,
        **store_backend.settings,
    )
    w = World(settings, FakeClock(T0 + timedelta(hours=1)))
    svc = await w.open()
    try:
        await svc.ingest("usv-old", "i1", samples(range(1, 4)))
        # The bucket's age is the point: real (monotonic) time has to pass it.
        await asyncio.sleep(0.35)
        await svc.ingest("usv-new", "i2", samples(range(1, 3)))
        await svc.ingest("usv-old", "i1", samples(range(4, 6)))  # the same open bucket
        assert await svc.write_due() == 1  # usv-old's, with all five; usv-new's is young
        assert await svc.write_due() == 0  # taken once
        await svc.make_durable()
        assert svc.durable_through_seq("usv-old") == 5
        assert svc.durable_through_seq("usv-new") == -1
        await svc.ingest("usv-old", "i1", samples(range(6, 8)))  # a new bucket opens
        deadline = time.monotonic() + 5
        written = 0
        while written < 2 and time.monotonic() < deadline:
            written += await svc.write_due()
            await asyncio.sleep(0.05)
        assert written == 2  # usv-new's first bucket and usv-old's second
        await svc.make_durable()
        assert (svc.durable_through_seq("usv-old"), svc.durable_through_seq("usv-new")) == (7, 2)
        page, _ = await svc.page("usv-old", limit=100)
        assert seqs_of(page) == list(range(1, 8))
    finally:
        await w.store.close()


async def test_buckets_packed_as_bson_before_are_read_beside_new_ones(world: World) -> None:
    """Buckets stored before samples were packed as JSON hold one BSON document: they are
    read as they were, in order with the buckets written since."""
    old = [s.model_dump(exclude_none=True) for s in samples(range(1, 4), battery_pct=50.0)]
    bucket = TelemetryRepo.make_bucket("usv-1", old)
    bucket["samples"] = bson.Binary(bson.encode({"s": old}))  # the packing before
    await world.svc.repo.insert(bucket)
    assert (await world.svc.last_seq("usv-1")) == 3
    await world.svc.ingest("usv-1", "i1", samples(range(4, 11)))
    await world.svc.flush_all()
    page, _ = await world.svc.page("usv-1", limit=100)
    assert seqs_of(page) == list(range(1, 11))
    assert [d.get("battery_pct") for d in page[:4]] == [50.0, 50.0, 50.0, None]
    assert page[0]["ts"] == T0 + timedelta(seconds=1)
    track = await world.svc.track("usv-1", T0, T0 + timedelta(hours=1))
    assert [p["seq"] for p in track.points] == list(range(1, 11))


async def test_a_window_from_within_a_samples_millisecond_finds_it(world: World) -> None:
    """A stored sample keeps its microseconds (the store keeps milliseconds of the bucket's
    bounds, and of a query's): a window opening within the sample's millisecond, before
    it, finds it once it is stored; one opening after it does not."""
    at = T0 + timedelta(seconds=5, microseconds=123_456)
    sample = Sample(seq=1, ts=at, lat=43.9, lon=15.4)
    await world.svc.ingest("usv-1", "i1", [sample])
    await world.svc.flush_all()
    world.svc = await world.restart()  # read back from the store, not the open bucket
    for start, found in ((at - timedelta(microseconds=400), [1]), (at, [1])):
        track = await world.svc.track("usv-1", start, at + timedelta(seconds=1))
        assert [p["seq"] for p in track.points] == found, start
        assert track.points[0]["ts"] == at
    after = await world.svc.track("usv-1", at + timedelta(microseconds=1), at + timedelta(1))
    assert after.points == []
