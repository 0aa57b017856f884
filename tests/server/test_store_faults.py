"""One record the store refuses, or a write failing half-way, never costs anything else.

Each test runs on the embedded store and on FerretDB. The faults are made by a store
whose collection refuses what the test names (the store itself is real)."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable, Iterable, Mapping, Sequence
from contextlib import asynccontextmanager
from datetime import UTC, datetime
from typing import Any

import httpx
import pytest
from asgi_lifespan import LifespanManager

from server.app import create_app
from server.errors import Unavailable
from server.settings import Settings
from server.storage import Collection, Rejected, Store, open_store
from server.storage.backends import Filter, SortSpec
from server.storage.commands import CommandsRepo
from tests.factories import ADMIN, make_vehicle, sample, start_instance

pytestmark = pytest.mark.usefixtures("store_backend")


class Faulty(Collection):
    """A real collection that refuses the inserts ``refuse`` picks, and the deletes while
    ``fail_deletes`` is set (as if the store went away between two writes)."""

    def __init__(self, inner: Collection, refuse: Callable[[dict[str, Any]], bool]) -> None:
        self.inner = inner
        self.name = inner.name
        self.refuse = refuse
        self.fail_deletes = False

    async def get(self, _id: Any) -> dict[str, Any] | None:
        return await self.inner.get(_id)

    async def get_many(self, ids: Iterable[Any]) -> list[dict[str, Any]]:
        return await self.inner.get_many(ids)

    async def insert(self, doc: dict[str, Any]) -> None:
        if self.refuse(doc):
            raise Rejected("refused by the test's store")
        await self.inner.insert(doc)

    async def insert_many(self, docs: Sequence[dict[str, Any]]) -> None:
        for doc in docs:
            await self.insert(doc)

    async def find(self, flt: Filter | None = None, **kwargs: Any) -> list[dict[str, Any]]:
        return await self.inner.find(flt, **kwargs)

    async def update(self, flt: Filter, **kwargs: Any) -> bool:
        return await self.inner.update(flt, **kwargs)

    async def replace(self, flt: Filter, doc: dict[str, Any], *, upsert: bool = False) -> bool:
        return await self.inner.replace(flt, doc, upsert=upsert)

    async def delete(self, flt: Filter) -> int:
        if self.fail_deletes:
            raise Unavailable("the store went away (the test's)")
        return await self.inner.delete(flt)

    async def count(self, flt: Filter | None = None) -> int:
        return await self.inner.count(flt)

    async def create_index(self, keys: SortSpec, *, unique: bool = False) -> None:
        await self.inner.create_index(keys, unique=unique)


def faulty_store(
    settings: Settings, faults: Mapping[str, Callable[[dict[str, Any]], bool]]
) -> Store:
    store = open_store(settings)
    plain = store._open

    def _open(name: str) -> Collection:
        inner = plain(name)
        return Faulty(inner, faults[name]) if name in faults else inner

    store._open = _open  # type: ignore[method-assign]
    return store


@asynccontextmanager
async def serving(
    settings: Settings, store: Store | None = None
) -> AsyncIterator[httpx.AsyncClient]:
    if store is not None:
        await store.load()
    app = create_app(settings, store=store)
    try:
        async with LifespanManager(app, startup_timeout=60) as m:
            transport = httpx.ASGITransport(app=m.app)
            async with httpx.AsyncClient(transport=transport, base_url="http://t") as c:
                yield c
    finally:
        if store is not None:
            await store.close()


async def send(
    c: httpx.AsyncClient, vid: str, vh: dict[str, str], iid: str, seqs: range
) -> dict[str, Any]:
    r = await c.post(
        "/upper/update_param",
        headers=vh,
        json={"instance_id": iid, "samples": [sample(n) for n in seqs]},
    )
    assert r.status_code == 200, r.text
    result: dict[str, Any] = r.json()
    return result


async def test_a_refused_bucket_costs_no_other_vehicle_its_samples(
    make_settings: Callable[..., Settings],
) -> None:
    settings = make_settings(bucket_samples=10, bucket_max_age_s=0.2, snapshot_interval_s=0.2)
    store = faulty_store(settings, {"telemetry": lambda doc: doc.get("vehicle_id") == "bad-1"})
    async with serving(settings, store) as c:
        vehicles = [await make_vehicle(c, vid) for vid in ("bad-1", "good-1", "good-2")]
        instances = [(await start_instance(c, vid, vh))["instance_id"] for vid, vh in vehicles]
        for (vid, vh), iid in zip(vehicles, instances, strict=True):
            for first in range(1, 31, 10):
                result = await send(c, vid, vh, iid, range(first, first + 10))
            assert result["acked_through_seq"] == 30

        async def durable(vid: str, vh: dict[str, str], iid: str) -> bool:
            return (await send(c, vid, vh, iid, range(0)))["durable_through_seq"] == 30

        async with asyncio.timeout(30):  # the writer, on its own beat, for every vehicle
            for (vid, vh), iid in zip(vehicles, instances, strict=True):
                while not await durable(vid, vh, iid):  # noqa: ASYNC110 (deadline poll)
                    await asyncio.sleep(0.05)
        kept = await c.get("/api/dead_letters", headers=ADMIN, params={"loop": "telemetry"})
        assert kept.status_code == 200, kept.text
        aside = kept.json()["dead_letters"]
        assert sorted(d["record_id"] for d in aside) == sorted(f"bad-1/{n}" for n in range(1, 31))
        assert all("refused by the test's store" in d["error"] for d in aside)
        assert "'seq': 7" in next(d["raw"] for d in aside if d["record_id"] == "bad-1/7")
        metrics = (await c.get("/metrics")).text
        assert 'fleet_background_errors_total{loop="telemetry"} 30.0' in metrics
    async with serving(settings) as c:  # a restart on the plain store
        for vid in ("good-1", "good-2"):
            page = (
                await c.get(f"/api/vehicles/{vid}/telemetry", headers=ADMIN, params={"limit": 100})
            ).json()
            assert [s["seq"] for s in page["samples"]] == list(range(1, 31)), vid


async def test_a_command_ending_while_the_store_fails_is_never_missing(
    make_settings: Callable[..., Settings],
) -> None:
    """Its end goes into the history first; the active copy goes after. The store failing
    between the two leaves it in both, readable and final, and a retry finishes the move."""
    settings = make_settings()
    faults: dict[str, Callable[[dict[str, Any]], bool]] = {"commands_active": lambda _doc: False}
    store = faulty_store(settings, faults)
    await store.load()
    repo = CommandsRepo(store)
    now = datetime.now(UTC)
    doc = {
        "command_id": "c-1",
        "instance_id": "i-1",
        "type": "stop",
        "args": {},
        "status": "queued",
        "issued_by": "ana",
        "issued_at": now,
        "expires_at": now,
        "history": [],
    }
    await repo.insert_active([doc])
    active = store["commands_active"]
    assert isinstance(active, Faulty)
    active.fail_deletes = True
    ended = {**doc, "status": "cancelled"}
    with pytest.raises(Unavailable):
        await repo.finish(ended, now)
    stored = await repo.get("c-1")
    assert stored is not None and stored["status"] == "cancelled"
    active.fail_deletes = False
    assert await repo.finish(ended, now) is False  # recorded already: only the move is done
    assert await repo.active_for("i-1") == []
    assert (await repo.get("c-1") or {})["status"] == "cancelled"
    await store.close()


async def test_buckets_stay_within_their_byte_bound(make_settings: Callable[..., Settings]) -> None:
    settings = make_settings(bucket_samples=10_000, bucket_max_bytes=65_536, bucket_max_age_s=0.2)
    reading = {"spectrum": list(range(900))}  # about 7 KiB of BSON a sample
    async with serving(settings) as c:
        vid, vh = await make_vehicle(c)
        iid = (await start_instance(c, vid, vh))["instance_id"]
        for first in range(1, 61, 20):
            r = await c.post(
                "/upper/update_param",
                headers=vh,
                json={
                    "instance_id": iid,
                    "samples": [sample(n, data=reading) for n in range(first, first + 20)],
                },
            )
            assert r.status_code == 200, r.text
        async with asyncio.timeout(30):
            while True:
                page = (
                    await c.get(
                        f"/api/vehicles/{vid}/telemetry", headers=ADMIN, params={"limit": 100}
                    )
                ).json()
                if len(page["samples"]) == 60:
                    break
                await asyncio.sleep(0.05)
    store = open_store(settings)
    await store.load()
    buckets = await store["telemetry"].find({"vehicle_id": vid}, projection={"samples": 0})
    await store.close()
    assert sum(b["n"] for b in buckets) == 60
    assert len(buckets) >= 6
    assert all(b["bytes"] <= 65_536 for b in buckets), [b["bytes"] for b in buckets]
