"""Two ``fleet-server`` processes on one FerretDB and one redis-server: a vehicle on
replica A, operators on replica B.

What this shows, with nothing shared but the store and Redis: the vehicle's presence
seen on B; a grant and a submit on B reaching the vehicle's socket on A, and its ack
seen on both; two replicas granting one instance at once leaving one holder that both
report; a token revoked on A refused on B (HTTP and an open socket) within one second;
one replica killed and the other going on.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import httpx
import pytest
import websockets
from pymongo import MongoClient

from tests.agent.procs import ADMIN_TOKEN, ServerProcess
from tests.bus.conftest import RedisServer
from tests.live import call, connect, recv_until
from tests.stores import MongoTarget

pytestmark = pytest.mark.slow

ADMIN = {"Authorization": f"Bearer {ADMIN_TOKEN}"}


def replica(workdir: Path, redis: RedisServer, mongo: MongoTarget) -> ServerProcess:
    workdir.mkdir(parents=True, exist_ok=True)
    server = ServerProcess(workdir)
    server.env.update(
        FLEET_MONGO_URL=mongo.url,
        FLEET_DB_NAME=mongo.db_name,
        FLEET_REDIS_URL=redis.url,
        FLEET_STALE_AFTER_S="1.5",
        FLEET_OFFLINE_AFTER_S="3",
        FLEET_STORE_TIMEOUT_MS="1000",
    )
    return server


@pytest.fixture
async def replicas(
    tmp_path: Path, redis_server: RedisServer, mongo_url: MongoTarget
) -> AsyncIterator[tuple[ServerProcess, ServerProcess]]:
    a = replica(tmp_path / "a", redis_server, mongo_url)
    b = replica(tmp_path / "b", redis_server, mongo_url)
    await asyncio.gather(asyncio.to_thread(a.start), asyncio.to_thread(b.start))
    try:
        for server in (a, b):
            await until(lambda s=server: ready(s), 30)
        yield a, b
    finally:
        await asyncio.gather(asyncio.to_thread(a.stop, 10), asyncio.to_thread(b.stop, 10))


async def ready(server: ServerProcess) -> bool:
    async with httpx.AsyncClient(timeout=5) as c:
        return (await c.get(f"{server.url}/readyz")).status_code == 200


async def until(probe: Callable[[], Any], within_s: float) -> Any:
    async with asyncio.timeout(within_s):
        while not (got := await probe()):  # noqa: ASYNC110 (deadline poll)
            await asyncio.sleep(0.05)
    return got


async def test_a_vehicle_on_a_and_operators_on_b(
    replicas: tuple[ServerProcess, ServerProcess], mongo_url: MongoTarget
) -> None:
    a, b = replicas
    async with (
        httpx.AsyncClient(base_url=a.url, timeout=10) as on_a,
        httpx.AsyncClient(base_url=b.url, timeout=10) as on_b,
    ):
        r = await on_a.post(
            "/api/vehicles", headers=ADMIN, json={"vehicle_id": "usv-1", "vehicle_type": "usv"}
        )
        vehicle_token = r.json()["token"]
        users = {}
        for name in ("ana", "ben"):
            r = await on_b.post(
                "/api/users",
                headers=ADMIN,
                json={"username": name, "role": "operator", "vehicles": ["usv-1"]},
            )
            assert r.status_code == 201, r.text
            users[name] = {"Authorization": f"Bearer {r.json()['token']}"}

        async with await connect(a.url, "/ws/vehicle", vehicle_token) as car:
            ack = await call(
                car, "start_instance", "s", vehicle_id="usv-1", capabilities=["stop", "go_to"]
            )
            iid = ack["instance_id"]

            # Presence: the vehicle talks to A; B sees it online.
            async def online_on_b() -> bool:
                r = await on_b.get("/api/vehicles/usv-1", headers=ADMIN)
                return r.json()["presence"] == "online"

            await until(online_on_b, 10)

            # Grant and submit on B; the command reaches the socket on A; its ack on both.
            r = await on_b.post(
                "/client/grant_control",
                headers=ADMIN,
                json={"instance_id": iid, "user": "ana", "duration_s": 600},
            )
            assert r.status_code == 200, r.text
            control = await recv_until(car, lambda f: f["op"] == "control", within_s=10)
            while (control.get("control") or {}).get("holder") != "ana":
                control = await recv_until(car, lambda f: f["op"] == "control", within_s=10)
            r = await on_b.post(
                "/client/submit_control",
                headers=users["ana"],
                json={
                    "instance_ids": [iid],
                    "command": {"type": "go_to", "args": {"lat": 43.9, "lon": 15.4}},
                },
            )
            assert r.status_code == 202, r.text
            cid = r.json()["commands"][0]["command_id"]
            pushed = await recv_until(car, lambda f: f["op"] == "command", within_s=10)
            assert pushed["command_id"] == cid
            for api in (on_a, on_b):
                assert (await api.get(f"/api/commands/{cid}", headers=ADMIN)).json()[
                    "status"
                ] == "delivered"
            ack = await call(
                car,
                "update_fbmessage",
                "f",
                instance_id=iid,
                acks=[{"command_id": cid, "status": "accepted"}],
            )
            assert ack["ok"], ack
            for api in (on_a, on_b):
                got = (await api.get(f"/api/commands/{cid}", headers=ADMIN)).json()
                assert got["status"] == "accepted", got

            # Both replicas grant at once, to two users: one holder, reported by both.
            grants = await asyncio.gather(
                *(
                    api.post(
                        "/client/grant_control",
                        headers=ADMIN,
                        json={"instance_id": iid, "user": name, "duration_s": 600},
                    )
                    for api, name in ((on_a, "ana"), (on_b, "ben"))
                )
            )
            assert [g.status_code for g in grants] == [200, 200], [g.text for g in grants]
            with MongoClient(mongo_url.url) as raw:
                leases = list(raw[mongo_url.db_name]["control"].find({"_id": iid}))
            assert len(leases) == 1
            holder = leases[0]["holder"]

            async def both_report_the_holder() -> bool:
                seen = []
                for api in (on_a, on_b):
                    r = await api.post(
                        "/client/connect_instance", headers=ADMIN, json={"instance_id": iid}
                    )
                    seen.append((r.json()["instance"]["control"] or {}).get("holder"))
                return seen == [holder, holder]

            await until(both_report_the_holder, 10)

            # A token revoked on A is refused on B within a second, open socket included.
            viewer = await on_a.post(
                "/api/users",
                headers=ADMIN,
                json={"username": "vic", "role": "viewer", "vehicles": ["usv-1"]},
            )
            vic_token = viewer.json()["token"]
            vic = {"Authorization": f"Bearer {vic_token}"}
            assert (await on_b.get("/api/vehicles", headers=vic)).status_code == 200  # cached
            async with await connect(b.url, "/ws/client", vic_token) as watcher:
                await call(watcher, "subscribe", "w", topics=["fleet"])
                r = await on_a.post("/api/users/vic/revoke_tokens", headers=ADMIN)
                assert r.status_code == 200, r.text
                revoked_at = time.monotonic()  # A has revoked it: B has a second

                async def refused_on_b() -> bool:
                    r = await on_b.get("/api/vehicles", headers=vic)
                    return r.status_code == 401

                await until(refused_on_b, 1.0)
                with pytest.raises(websockets.ConnectionClosed) as closed:
                    async with asyncio.timeout(max(0.0, 1.0 - (time.monotonic() - revoked_at))):
                        while True:  # the fleet's events, until the socket is closed
                            await watcher.recv()
                assert closed.value.rcvd is not None and closed.value.rcvd.code == 4401

        # One replica killed: the other goes on, with the vehicle on it.
        await asyncio.to_thread(b.kill)
        async with await connect(a.url, "/ws/vehicle", vehicle_token) as car:
            again = await call(
                car, "start_instance", "s2", vehicle_id="usv-1", capabilities=["stop", "go_to"]
            )
            assert again["instance_id"] == iid and again["resumed"] is True
            r = await on_a.post(
                "/client/submit_control",
                headers=ADMIN,
                json={"instance_ids": [iid], "command": {"type": "stop"}},
            )
            assert r.status_code == 202, r.text
            pushed = await recv_until(car, lambda f: f["op"] == "command", within_s=10)
            assert pushed["type"] == "stop"
        assert (await on_a.get("/readyz")).status_code == 200
