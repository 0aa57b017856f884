"""Presence told once, whichever of several replicas on one store sees the change first.

The replicas here are whole apps on ONE store object and a clock the test moves; their
sweeps are run together (``asyncio.gather``), so on FerretDB their store calls reach the
server at the same moment. FerretDB 1.24 does not serialise a conditional update (it reads
the document, applies the update and writes the whole document back): a claim made that
way was won by both replicas, and a contact write racing it put the former presence back.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable
from contextlib import AsyncExitStack, asynccontextmanager
from datetime import UTC, datetime, timedelta

import httpx
import pytest
from asgi_lifespan import LifespanManager

from server.app import create_app
from server.services.instances import InstanceService
from server.settings import Settings
from server.storage import Store, open_store
from server.storage.instances import InstancesRepo
from tests.factories import ADMIN, FakeClock, make_vehicle, start_instance

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")

T0 = datetime(2026, 11, 24, 12, 0, 0, tzinfo=UTC)


@asynccontextmanager
async def shared_store(make_settings: Callable[..., Settings]) -> AsyncIterator[Store]:
    store = open_store(make_settings())
    await store.load()
    try:
        yield store
    finally:
        await store.close()


async def test_of_claims_of_one_change_at_once_one_wins(
    make_settings: Callable[..., Settings],
) -> None:
    async with shared_store(make_settings) as store:
        repo = InstancesRepo(store)
        await repo.ensure_indexes()
        for n in range(5):
            iid = f"i-{n}"
            await repo.insert({"instance_id": iid, "vehicle_id": "v", "last_seen": T0})
            # Four replicas claim the first change while a fifth writes the contact back.
            *won, _ = await asyncio.gather(
                *(repo.claim_presence(iid, 1, "stale", T0) for _ in range(4)),
                repo.save(iid, {"last_seen": T0 + timedelta(seconds=1), "position": None}),
            )
            assert won.count(True) == 1, won
            assert not await repo.claim_presence(iid, 1, "offline", T0)  # still taken
            assert await repo.last_presence(iid) == {
                "_id": f"{iid}/000001",
                "instance_id": iid,
                "seq": 1,
                "presence": "stale",
                "at": T0,
            }
            assert await repo.claim_presence(iid, 2, "offline", T0)


async def test_the_record_notes_the_latest_change_and_retention_drops_them_all(
    make_settings: Callable[..., Settings],
) -> None:
    async with shared_store(make_settings) as store:
        repo = InstancesRepo(store)
        await repo.insert({"instance_id": "i-1", "vehicle_id": "v", "presence_seq": 0})
        await repo.note_presence("i-1", 2, "offline")
        await repo.note_presence("i-1", 1, "stale")  # late: an earlier change never wins
        doc = await repo.get("i-1")
        assert doc is not None and (doc["presence"], doc["presence_seq"]) == ("offline", 2)
        await repo.claim_presence("i-1", 1, "stale", T0)
        await repo.claim_presence("i-1", 2, "offline", T0)
        await repo.save("i-1", {"finished_at": T0})
        assert await repo.drop_finished_before(T0 + timedelta(seconds=1)) == 1
        assert await repo.get("i-1") is None and await repo.last_presence("i-1") is None


@asynccontextmanager
async def replicas(
    make_settings: Callable[..., Settings], clock: FakeClock, n: int
) -> AsyncIterator[list[tuple[httpx.AsyncClient, InstanceService]]]:
    """``n`` apps on one store and one clock: an HTTP client and the instances of each."""
    settings = make_settings()
    async with shared_store(make_settings) as store, AsyncExitStack() as stack:
        out = []
        for _ in range(n):
            app = create_app(settings, clock=clock, store=store)
            manager = await stack.enter_async_context(LifespanManager(app))
            http = await stack.enter_async_context(
                httpx.AsyncClient(
                    transport=httpx.ASGITransport(app=manager.app), base_url="http://t"
                )
            )
            out.append((http, app.state.services.instances))
        yield out


async def test_replicas_seeing_a_vehicle_go_quiet_together_tell_each_change_once(
    make_settings: Callable[..., Settings], clock: FakeClock
) -> None:
    async with replicas(make_settings, clock, 3) as apps:
        http = apps[0][0]
        vid, vehicle = await make_vehicle(http)
        iid = (await start_instance(http, vid, vehicle))["instance_id"]
        for _, instances in apps:
            await instances.find(iid)  # each replica keeps a copy

        async def sweep() -> None:
            await asyncio.gather(*(i.sweep(everything=True) for _, i in apps))

        async def told() -> list[str]:
            r = await http.get(
                "/api/events", headers=ADMIN, params={"vehicle_id": vid, "kind": "presence"}
            )
            assert r.status_code == 200, r.text
            return [e["data"]["presence"] for e in r.json()["events"]]

        async def heartbeat(through: httpx.AsyncClient) -> None:
            r = await through.post("/upper/heartbeat", headers=vehicle, json={"instance_id": iid})
            assert r.status_code == 200, r.text

        async def quiet() -> None:
            clock.advance(5)
            await sweep()
            clock.advance(10)
            await sweep()

        await quiet()
        assert await told() == ["stale", "offline"]
        # Back through the last replica, quiet again: the others' copies lag behind.
        await heartbeat(apps[2][0])
        await sweep()
        await quiet()
        assert await told() == ["stale", "offline", "online", "stale", "offline"]
        # Back through the first replica, which catches up with the changes told since.
        await heartbeat(http)
        await sweep()
        await sweep()
        assert await told() == ["stale", "offline", "online", "stale", "offline", "online"]
