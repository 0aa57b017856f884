"""The real MongoDB driver path, on FerretDB: what only a store of its own process shows.

A store that is down when the server starts, two replicas starting at once, two
replicas granting one lease at once, and the write concern the server asks for.
(``FLEET_TEST_MONGO_URL`` runs them against any MongoDB instead.)
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable
from contextlib import AsyncExitStack, asynccontextmanager
from typing import Any

import httpx
from asgi_lifespan import LifespanManager
from fastapi import FastAPI
from pymongo import MongoClient

from server.app import create_app
from server.settings import Settings
from tests.factories import ADMIN, make_user, make_vehicle, start_instance
from tests.stores import FerretDB, MongoTarget


def client_of(app: FastAPI) -> httpx.AsyncClient:
    return httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://t")


@asynccontextmanager
async def running(*apps: FastAPI) -> AsyncIterator[list[httpx.AsyncClient]]:
    """The apps started at the same moment, and a client to each."""
    async with AsyncExitStack() as stack:
        managers = await asyncio.gather(
            *(stack.enter_async_context(LifespanManager(a, startup_timeout=60)) for a in apps)
        )
        yield [await stack.enter_async_context(client_of(m.app)) for m in managers]


async def until(probe: Callable[[], Any], within_s: float) -> Any:
    async with asyncio.timeout(within_s):
        while not (got := await probe()):  # noqa: ASYNC110 (deadline poll)
            await asyncio.sleep(0.1)
    return got


async def test_a_store_down_at_start_is_waited_for_and_then_served(
    make_ferretdb: Callable[[], FerretDB], make_settings: Callable[..., Settings]
) -> None:
    store = make_ferretdb()
    await asyncio.to_thread(store.stop)
    settings = make_settings(
        mongo_url=store.url, db_name="fleet", store_timeout_ms=300, store_retry_max_s=0.5
    )
    async with running(create_app(settings)) as (c,):
        r = await c.get("/readyz")
        assert r.status_code == 503 and r.headers["Retry-After"]
        assert "unreachable" in r.json()["reasons"]["store"]
        r = await c.get("/api/vehicles", headers=ADMIN)
        assert r.status_code == 503 and r.headers["Retry-After"]
        assert r.json()["error"]["code"] == "unavailable"
        await asyncio.to_thread(store.start)

        async def ready() -> bool:
            return (await c.get("/readyz")).status_code == 200

        await until(ready, 30)
        r = await c.get("/api/vehicles", headers=ADMIN)  # the admin was made once it came
        assert r.status_code == 200, r.text
        vid, vh = await make_vehicle(c)
        assert (await start_instance(c, vid, vh))["resumed"] is False


async def test_two_replicas_starting_together_make_one_admin(
    mongo_url: MongoTarget, make_settings: Callable[..., Settings]
) -> None:
    for admin_token in (None, "fct_test-admin-token-0123456789"):
        settings = make_settings(
            mongo_url=mongo_url.url, db_name=mongo_url.db_name, admin_token=admin_token
        )
        apps = [create_app(settings), create_app(settings)]
        async with running(*apps) as clients:
            tokens = [a.state.runtime.admin_token for a in apps]
            headers = (
                [ADMIN]
                if admin_token
                else [{"Authorization": f"Bearer {t}"} for t in tokens if t is not None]
            )
            ok = 0
            for headers_ in headers:
                for c in clients:
                    r = await c.get("/api/users", headers=headers_)
                    if r.status_code == 200:
                        ok += 1
                        assert [u["username"] for u in r.json()["users"]] == ["admin"]
            assert ok >= len(clients)  # the token that stands works on both replicas
    with MongoClient(mongo_url.url) as raw:
        assert raw[mongo_url.db_name]["users"].count_documents({}) == 1


async def test_one_lease_per_instance_when_two_replicas_grant_at_once(
    mongo_url: MongoTarget, make_settings: Callable[..., Settings]
) -> None:
    settings = make_settings(mongo_url=mongo_url.url, db_name=mongo_url.db_name)
    async with running(create_app(settings), create_app(settings)) as (a, b):
        vid, vh = await make_vehicle(a)
        iid = (await start_instance(a, vid, vh))["instance_id"]
        users = [await make_user(a, "operator", [vid]) for _ in range(2)]
        for _ in range(5):
            grants = await asyncio.gather(
                *(
                    c.post(
                        "/client/grant_control",
                        headers=ADMIN,
                        json={"instance_id": iid, "user": name, "duration_s": 60},
                    )
                    for c, (name, _) in zip((a, b), users, strict=True)
                )
            )
            assert all(g.status_code == 200 for g in grants), [g.text for g in grants]
            with MongoClient(mongo_url.url) as raw:
                leases = list(raw[mongo_url.db_name]["control"].find({}))
            assert len(leases) == 1
            holder = leases[0]["holder"]
            # Every decision, on either replica, reads the one lease the store holds.
            for c in (a, b):
                for name, headers in users:
                    r = await c.post(
                        "/client/submit_control",
                        headers=headers,
                        json={
                            "instance_ids": [iid],
                            "command": {"type": "go_to", "args": {"lat": 43.9, "lon": 15.4}},
                        },
                    )
                    assert r.status_code == (202 if name == holder else 409), r.text


async def test_the_write_concern_is_a_setting_majority_and_journaled_by_default(
    mongo_url: MongoTarget, make_settings: Callable[..., Settings]
) -> None:
    cases = [
        ({}, "w=majority, j=true"),
        ({"store_write_concern": "1", "store_journal": False}, "w=1, j=false"),
    ]
    for overrides, said in cases:
        settings = make_settings(mongo_url=mongo_url.url, db_name=mongo_url.db_name, **overrides)
        async with running(create_app(settings)) as (c,):
            ready = (await c.get("/readyz")).json()
            assert (ready["store"], ready["durability"]) == ("mongodb", said)


async def test_a_store_lost_under_a_running_server_is_503_and_comes_back(
    make_ferretdb: Callable[[], FerretDB], make_settings: Callable[..., Settings]
) -> None:
    store = make_ferretdb()
    settings = make_settings(mongo_url=store.url, db_name="fleet", store_timeout_ms=300)
    async with running(create_app(settings)) as (c,):
        vid, vh = await make_vehicle(c)
        await asyncio.to_thread(store.kill)
        with contextlib.suppress(httpx.HTTPError):
            r = await asyncio.wait_for(c.get("/api/vehicles", headers=ADMIN), 30)
            assert r.status_code == 503 and r.headers["Retry-After"]
        assert (await asyncio.wait_for(c.get("/readyz"), 30)).status_code == 503
        await asyncio.to_thread(store.start)

        async def back() -> bool:
            return (await c.get("/api/vehicles", headers=ADMIN)).status_code == 200

        await until(back, 30)
        assert (await start_instance(c, vid, vh))["resumed"] is False
