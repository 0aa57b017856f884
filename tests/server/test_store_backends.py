"""The store's one interface, on each backend: the embedded store and FerretDB (the real
MongoDB driver path). The same calls must give the same answers and the same errors."""

from __future__ import annotations

import asyncio
import random
from collections.abc import AsyncIterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
from bson import ObjectId

from server.settings import Settings
from server.storage import Duplicate, Rejected, Store, open_store
from tests.stores import StoreBackend

pytestmark = pytest.mark.usefixtures("store_backend")

T0 = datetime(2026, 11, 24, 12, 0, 0, tzinfo=UTC)


@pytest.fixture
async def store(tmp_path: Path, store_backend: StoreBackend) -> AsyncIterator[Store]:
    settings = Settings(
        _env_file=None,
        snapshot_path=tmp_path / "store.snapshot",  # type: ignore[call-arg]
        **store_backend.settings,
    )
    opened = open_store(settings)
    await opened.load()
    try:
        yield opened
    finally:
        await opened.close()


async def test_keyed_reads_and_writes(store: Store) -> None:
    coll = store["things"]
    await coll.insert({"_id": "a", "n": 1, "at": T0})
    await coll.insert({"_id": "b", "n": 2, "at": T0 + timedelta(microseconds=1500)})
    got = await coll.get("a")
    assert got == {"_id": "a", "n": 1, "at": T0}
    assert got["at"].tzinfo is not None  # UTC-aware on both backends
    b = await coll.get("b")
    assert b is not None and b["at"] == T0 + timedelta(milliseconds=1)  # BSON's precision
    assert await coll.get("nope") is None
    assert sorted(d["_id"] for d in await coll.get_many(["a", "b", "c"])) == ["a", "b"]
    with pytest.raises(Duplicate):
        await coll.insert({"_id": "a", "n": 9})
    assert (await coll.get("a") or {})["n"] == 1


async def test_updates_set_max_unset_and_conditions(store: Store) -> None:
    coll = store["things"]
    await coll.insert({"_id": "a", "n": 1, "seen": T0, "gone": True})
    assert await coll.update({"_id": "a"}, set={"n": 2}, max={"seen": T0 - timedelta(1)})
    assert await coll.update({"_id": "a"}, unset=["gone"])
    assert await coll.get("a") == {"_id": "a", "n": 2, "seen": T0}
    assert await coll.update({"_id": "a"}, max={"seen": T0 + timedelta(seconds=1)})
    assert (await coll.get("a") or {})["seen"] == T0 + timedelta(seconds=1)
    # A condition that does not hold changes nothing (compare and set).
    assert not await coll.update({"_id": "a", "n": 1}, set={"n": 3})
    assert await coll.update({"_id": "a", "n": {"$ne": 3}}, set={"n": 3})
    assert not await coll.update({"_id": "a", "n": {"$ne": 3}}, set={"n": 3})
    assert not await coll.update({"_id": "zz"}, set={"n": 1})
    assert await coll.update({"_id": "zz"}, set={"n": 1}, upsert=True)
    assert await coll.get("zz") == {"_id": "zz", "n": 1}


async def test_replace_delete_count(store: Store) -> None:
    coll = store["things"]
    await coll.insert_many([{"_id": i, "k": i % 3, "rev": 1} for i in range(10)])
    assert await coll.count() == 10
    assert await coll.count({"k": 0}) == 4
    assert await coll.replace({"_id": 3, "rev": 1}, {"_id": 3, "k": 9, "rev": 2})
    assert not await coll.replace({"_id": 3, "rev": 1}, {"_id": 3, "k": 8, "rev": 3})
    assert (await coll.get(3) or {})["k"] == 9
    assert await coll.delete({"k": 0}) == 3  # 0, 6, 9 (3 was replaced)
    assert await coll.delete({"_id": 3, "rev": 1}) == 0
    assert await coll.delete({"_id": 3, "rev": 2}) == 1
    assert await coll.count() == 6  # 10 less 0, 6, 9 and 3


async def test_a_record_bson_cannot_hold_is_rejected_and_nothing_changes(store: Store) -> None:
    coll = store["things"]
    for bad in ({"n": 2**64}, {"s": "\ud800"}, {"d": {"a\x00b": 1}}):
        with pytest.raises(Rejected):
            await coll.insert({"_id": "x", **bad})
        assert await coll.get("x") is None
    await coll.insert({"_id": "x", "n": 1})
    with pytest.raises(Rejected):
        await coll.update({"_id": "x"}, set={"n": -(2**63) - 1})
    assert (await coll.get("x") or {})["n"] == 1


async def test_unique_index_refuses_a_second_key(store: Store) -> None:
    coll = store["things"]
    await coll.create_index([("name", 1)], unique=True)
    await coll.insert({"_id": 1, "name": "a"})
    with pytest.raises(Duplicate):
        await coll.insert({"_id": 2, "name": "a"})
    await coll.insert({"_id": 3, "name": "b"})
    assert await coll.count() == 2


@pytest.mark.parametrize("object_ids", [False, True], ids=["int-ids", "objectid-ids"])
async def test_indexed_queries_answer_as_a_scan_would(store: Store, object_ids: bool) -> None:
    """The embedded store plans these shapes on its ordered indexes; MongoDB on its own.
    Both must give what a plain reading of the filter gives (with the ``_id`` a driver
    makes, an ObjectId, too: the embedded index keeps it as its bytes)."""
    rng = random.Random(7)
    coll = store["buckets"]
    await coll.create_index([("vehicle_id", 1), ("max_seq", 1)])
    await coll.create_index([("vehicle_id", 1), ("end", 1)])
    await coll.create_index([("end", 1)])
    docs: list[dict[str, Any]] = []
    seqs = rng.sample(range(1000), 300)  # no ties: the two backends may order ties apart
    for i in range(300):
        start = T0 + timedelta(seconds=rng.randrange(0, 3600), milliseconds=i)
        docs.append(
            {
                "_id": ObjectId(i.to_bytes(12, "big")) if object_ids else i,
                "vehicle_id": rng.choice(["usv-1", "usv-2", "auv-3"]),
                "max_seq": seqs[i],
                "start": start,
                "end": start + timedelta(seconds=rng.randrange(0, 300)),
            }
        )
    await coll.insert_many(docs)
    for _ in range(40):
        vid = rng.choice(["usv-1", "usv-2", "auv-3", "none"])
        after = rng.randrange(0, 1000)
        lo = T0 + timedelta(seconds=rng.randrange(0, 3600))
        hi = lo + timedelta(seconds=rng.randrange(1, 900))
        cases: list[tuple[dict[str, Any], list[tuple[str, int]], int]] = [
            ({"vehicle_id": vid, "max_seq": {"$gt": after}}, [("max_seq", 1)], 5),
            ({"vehicle_id": vid}, [("max_seq", -1)], 1),
            ({"vehicle_id": vid, "end": {"$gte": lo}, "start": {"$lt": hi}}, [("_id", 1)], 0),
            ({"end": {"$lt": lo}}, [("_id", 1)], 0),
            ({"vehicle_id": vid, "end": {"$gte": lo, "$lte": hi}}, [("end", 1), ("_id", 1)], 0),
        ]
        for flt, sort, limit in cases:
            got = await coll.find(flt, sort=sort, limit=limit)
            want = _plain(docs, flt, sort, limit)
            assert [d["_id"] for d in got] == [d["_id"] for d in want], (flt, sort, limit)


def _plain(
    docs: list[dict[str, Any]], flt: dict[str, Any], sort: list[tuple[str, int]], limit: int
) -> list[dict[str, Any]]:
    ops = {
        "$gt": lambda a, b: a > b,
        "$gte": lambda a, b: a >= b,
        "$lt": lambda a, b: a < b,
        "$lte": lambda a, b: a <= b,
    }

    def matches(doc: dict[str, Any]) -> bool:
        for key, cond in flt.items():
            if isinstance(cond, dict):
                if not all(ops[op](doc[key], bound) for op, bound in cond.items()):
                    return False
            elif doc[key] != cond:
                return False
        return True

    out = [d for d in docs if matches(d)]
    for key, direction in reversed(sort):
        out.sort(key=lambda d, k=key: d[k], reverse=direction < 0)
    return out[:limit] if limit else out


async def test_projection(store: Store) -> None:
    coll = store["things"]
    await coll.insert({"_id": "a", "x": 1, "y": 2, "secret": 3})
    assert await coll.find({}, projection={"secret": 0}) == [{"_id": "a", "x": 1, "y": 2}]
    assert await coll.find({}, projection={"x": 1}) == [{"_id": "a", "x": 1}]
    assert await coll.find({}, projection={"_id": 0, "y": 1}) == [{"y": 2}]
    assert await coll.find({}, projection={"_id": 1}) == [{"_id": "a"}]
    assert await coll.find({}, projection={"_id": 0}) == [{"x": 1, "y": 2, "secret": 3}]
    assert await coll.find({}, projection={"x": 1, "gone": 1}) == [{"_id": "a", "x": 1}]


async def test_a_range_matches_its_own_type_only(store: Store) -> None:
    """On an indexed field too, a range takes values of its bound's type (BSON's type
    brackets): no null, number or string is below a date, no date above a number."""
    coll = store["mixed"]
    await coll.create_index([("at", 1)])
    values: dict[str, Any] = {
        "null": None,
        "zero": 0,
        "big": 10**12,
        "text": "2026",
        "early": T0 - timedelta(days=1),
        "late": T0 + timedelta(days=1),
        "yes": True,
    }
    for name, value in values.items():
        await coll.insert({"_id": name, "at": value})
    await coll.insert({"_id": "missing"})

    async def ids(flt: dict[str, Any]) -> list[str]:
        return sorted(d["_id"] for d in await coll.find(flt))

    assert await ids({"at": {"$lt": T0}}) == ["early"]
    assert await ids({"at": {"$gte": T0}}) == ["late"]
    assert await ids({"at": {"$gt": 5}}) == ["big"]
    assert await ids({"at": {"$lte": 5}}) == ["zero"]
    assert await ids({"at": {"$gte": ""}}) == ["text"]
    assert await ids({"at": {"$gt": 5, "$lt": T0}}) == []
    assert await coll.delete({"at": {"$lt": T0}}) == 1
    assert await ids({}) == ["big", "late", "missing", "null", "text", "yes", "zero"]


async def test_equalities_match_as_mongodb_matches_them(store: Store) -> None:
    """Null matches a missing field; a string matches an array holding it; a datetime
    matches the same instant; nothing matches across types."""
    coll = store["plain"]
    await coll.insert({"_id": "missing", "tag": "a"})
    await coll.insert({"_id": "null", "tag": "b", "done": None})
    await coll.insert({"_id": "set", "tag": ["a", "c"], "done": T0})
    await coll.insert({"_id": "other", "tag": "c", "done": "2026-11-24T12:00:00Z"})

    async def ids(flt: dict[str, Any]) -> list[str]:
        return sorted(d["_id"] for d in await coll.find(flt))

    assert await ids({"done": None}) == ["missing", "null"]
    assert await ids({"tag": "a"}) == ["missing", "set"]
    assert await ids({"tag": "c", "done": T0}) == ["set"]
    assert await ids({"done": T0}) == ["set"]
    assert await ids({"done": "2026-11-24T12:00:00Z"}) == ["other"]
    assert await ids({"tag": "a", "done": None}) == ["missing"]


@pytest.fixture
async def other_replica(
    tmp_path: Path, store_backend: StoreBackend, store: Store
) -> AsyncIterator[Store]:
    """The store as a second replica has it: its own client on the same database (the
    embedded store lives in one process: the same store)."""
    if store_backend.name == "embedded":
        yield store
        return
    settings = Settings(_env_file=None, **store_backend.settings)  # type: ignore[call-arg]
    opened = open_store(settings)
    try:
        yield opened
    finally:
        await opened.close()


async def test_a_compare_and_set_has_one_winner_however_many_replicas_race(
    store: Store, other_replica: Store
) -> None:
    """Four writers, two per replica, each changing one document from the revision they
    read: one wins each round. And writes of other fields of the document at the same
    time are all kept (none undoes another)."""
    colls = [store["cas"], other_replica["cas"]]
    for doc_id in range(40):
        await colls[0].insert({"_id": doc_id, "rev": 0})
        won = await asyncio.gather(
            *(
                colls[i % 2].update({"_id": doc_id, "rev": 0}, set={"rev": 1, "by": i})
                for i in range(4)
            )
        )
        assert sum(won) == 1, (doc_id, won)
        moved = await asyncio.gather(
            *(colls[i % 2].update({"_id": doc_id}, set={f"f{i}": i}) for i in range(4)),
            *(colls[i % 2].update({"_id": doc_id, "rev": 1}, set={"rev": 2}) for i in range(2)),
        )
        assert moved[:4] == [True] * 4 and sum(moved[4:]) == 1, (doc_id, moved)
        got = await colls[0].get(doc_id) or {}
        assert got["rev"] == 2 and {k: v for k, v in got.items() if k[0] == "f"} == {
            f"f{i}": i for i in range(4)
        }, got
