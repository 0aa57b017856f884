"""Two server replicas joined by a real Redis: operator events cross, Redis loss degrades.

Replicas share state only through MongoDB: the command path across replicas
runs on FerretDB (or FLEET_TEST_MONGO_URL); topic traffic between users needs
no shared state (the bootstrap admin exists on both).
test_replicas_processes.py runs two fleet-server processes.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager

import httpx

from server.settings import Settings
from tests.bus.conftest import RedisServer
from tests.factories import ADMIN, ADMIN_TOKEN, make_user, make_vehicle
from tests.live import call, connect, recv_until, serve
from tests.stores import MongoTarget


async def _get(url: str) -> httpx.Response:
    async with httpx.AsyncClient(timeout=10) as client:
        return await client.get(url)


@asynccontextmanager
async def _two_replicas(
    make_settings: Callable[..., Settings], redis: RedisServer
) -> AsyncIterator[tuple[str, str]]:
    """Two replicas joined by ``redis``, each on its own embedded store: their URLs."""
    a_settings = make_settings(redis_url=redis.url)
    b_settings = make_settings(
        redis_url=redis.url, snapshot_path=a_settings.snapshot_path.with_name("b.snapshot")
    )
    async with serve(a_settings) as a, serve(b_settings) as b:
        yield a, b


async def test_events_published_on_one_replica_reach_the_other(
    make_settings: Callable[..., Settings], redis_server: RedisServer
) -> None:
    async with _two_replicas(make_settings, redis_server) as (a, b):
        for base in (a, b):
            ready = (await _get(f"{base}/readyz")).json()
            assert ready["checks"] == {"store": True, "redis": True}
        async with (
            await connect(b, "/ws/client", ADMIN_TOKEN) as listener,
            await connect(a, "/ws/client", ADMIN_TOKEN) as talker,
        ):
            assert (await call(listener, "subscribe", "s", topics=["user/admin/notes"]))["ok"]
            assert (
                await call(talker, "publish", "p", topic="user/admin/notes", data={"from": "a"})
            )["ok"]
            got = await recv_until(listener, lambda f: f["op"] == "event")
            assert got["data"] == {"from": "a"} and got["topic"] == "user/admin/notes"


async def test_a_topics_latest_message_published_on_one_replica_is_the_others_snapshot(
    make_settings: Callable[..., Settings], redis_server: RedisServer
) -> None:
    async with _two_replicas(make_settings, redis_server) as (a, b):
        async with await connect(a, "/ws/client", ADMIN_TOKEN) as talker:
            for n in range(2):
                said = await call(talker, "publish", f"p{n}", topic="user/admin/plan", data=n)
                assert said["ok"]
        async with await connect(b, "/ws/client", ADMIN_TOKEN) as late:
            assert (await call(late, "subscribe", "s", topics=["user/admin/plan"]))["ok"]
            first = await recv_until(late, lambda f: f["op"] == "event")
            assert (first["data"], first["snapshot"]) == (1, True)


async def test_a_gateway_forwards_up_what_a_subscriber_on_the_other_replica_wants(
    make_settings: Callable[..., Settings], redis_server: RedisServer
) -> None:
    """Each replica's routing table held its own units alone: a gateway on one replica
    kept to itself a topic that only an operator on the other wanted."""
    async with _two_replicas(make_settings, redis_server) as (a, b):
        async with httpx.AsyncClient(base_url=a, timeout=10) as api:
            vid, _ = await make_vehicle(api)
            body = {"gateway_id": "gw-far", "vehicles": [vid]}
            gw = (await api.post("/api/gateways", headers=ADMIN, json=body)).json()["token"]
        topic = f"vehicle/{vid}/sss_meta"
        async with await connect(a, "/ws/vehicle", gw) as g:
            assert (await call(g, "register", "r", topics=[topic], vehicle_id=vid))["ok"]
            async with await connect(b, "/ws/client", ADMIN_TOKEN) as far:
                assert (await call(far, "subscribe", "s", topics=[topic]))["ok"]
                routes = await recv_until(
                    g, lambda f: f["op"] == "routes" and f.get("forward_up") == [topic]
                )
                assert routes["unit"] == "gateway:gw-far"
                said = await call(g, "publish", "p", topic=topic, data=1, vehicle_id=vid)
                assert said["ok"]
                assert (await recv_until(far, lambda f: f["op"] == "event"))["data"] == 1
            # the operator gone, the other replica says so: nothing more goes up
            await recv_until(g, lambda f: f["op"] == "routes" and f.get("forward_up") == [])


async def test_redis_going_away_degrades_to_local_and_shows_in_readyz(
    make_settings: Callable[..., Settings], redis_server: RedisServer
) -> None:
    async with serve(make_settings(redis_url=redis_server.url)) as base:
        redis_server.stop()
        async with asyncio.timeout(20):
            while True:
                r = await _get(f"{base}/readyz")
                if r.json()["status"] == "degraded":
                    break
                await asyncio.sleep(0.1)
        # degraded, not out of service: a load balancer keeps sending this replica its sockets
        assert r.status_code == 200 and r.json()["ready"] is True
        assert r.json()["checks"] == {"store": True, "redis": False}
        assert "Redis" in r.json()["reasons"]["redis"]
        async with (
            await connect(base, "/ws/client", ADMIN_TOKEN) as one,
            await connect(base, "/ws/client", ADMIN_TOKEN) as two,
        ):
            await call(one, "subscribe", "s", topics=["user/admin/local"])
            await call(two, "publish", "p", topic="user/admin/local", data=1)
            got = await recv_until(one, lambda f: f["op"] == "event")
            assert got["data"] == 1  # this replica's own sockets are still served
        redis_server.start()
        async with asyncio.timeout(30):
            while (await _get(f"{base}/readyz")).json()["status"] != "ok":  # noqa: ASYNC110 (deadline poll)
                await asyncio.sleep(0.2)


async def test_command_accepted_on_a_reaches_vehicle_on_b(
    make_settings: Callable[..., Settings], redis_server: RedisServer, mongo_url: MongoTarget
) -> None:
    common = {
        "redis_url": redis_server.url,
        "mongo_url": mongo_url.url,
        "db_name": mongo_url.db_name,
    }
    async with serve(make_settings(**common)) as a, serve(make_settings(**common)) as b:
        async with httpx.AsyncClient(base_url=a, timeout=10) as api_a:
            vid, vh = await make_vehicle(api_a)
            user, op = await make_user(api_a, "operator", [vid])
            async with await connect(b, "/ws/vehicle", vh["Authorization"][7:]) as car:
                ack = await call(
                    car, "start_instance", "s", vehicle_id=vid, capabilities=["stop", "go_to"]
                )
                iid = ack["instance_id"]
                r = await api_a.post(
                    "/client/grant_control",
                    headers=ADMIN,
                    json={"instance_id": iid, "user": user, "duration_s": 60},
                )
                assert r.status_code == 200
                r = await api_a.post(
                    "/client/submit_control",
                    headers=op,
                    json={"instance_ids": [iid], "command": {"type": "stop"}},
                )
                assert r.status_code == 202
                pushed = await recv_until(car, lambda f: f["op"] == "command", within_s=15)
                assert pushed["type"] == "stop"
                command_id = pushed["command_id"]
                done = await call(
                    car,
                    "update_fbmessage",
                    "f",
                    instance_id=iid,
                    acks=[{"command_id": command_id, "status": "accepted"}],
                )
                assert done["ok"], done
                r = await api_a.get(f"/api/commands/{command_id}", headers=op)
                assert r.status_code == 200 and r.json()["status"] == "accepted", r.text
