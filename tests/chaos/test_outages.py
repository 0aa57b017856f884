"""Outages under a running fleet, with real processes: Redis cut off under one of two
replicas (it degrades, serves its own sockets, and delivery between replicas resumes),
and the store gone (503 with ``Retry-After``, never a hang; nothing lost after it).

Short here (``make test``); ``make chaos`` runs the same (``tests/chaos/conftest.py``).
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import pytest

from bench._faults import FaultProxy
from tests.agent.procs import ADMIN_TOKEN, AgentProcess, Fleet, ServerProcess, wait_until
from tests.bus.conftest import RedisServer
from tests.chaos.checks import assert_exactly_once, has_stored, stored_through
from tests.chaos.conftest import FULL, scaled
from tests.live import call, connect, recv_until
from tests.stores import FerretDB, MongoTarget

pytestmark = [pytest.mark.slow, *([pytest.mark.timeout(3600)] if FULL else [])]

ADMIN = {"Authorization": f"Bearer {ADMIN_TOKEN}"}


# ---- Redis cut off under one of two replicas ---------------------------------------------


async def _status(client: httpx.AsyncClient, server: ServerProcess) -> str:
    return (await client.get(f"{server.url}/readyz")).json()["status"]


async def _until(probe: Callable[[], Any], within_s: float) -> Any:
    async with asyncio.timeout(within_s):
        while not (got := await probe()):  # noqa: ASYNC110 (deadline poll)
            await asyncio.sleep(0.1)
    return got


async def test_redis_cut_off_under_one_replica_degrades_it_and_delivery_resumes(
    tmp_path: Path,
    redis_server: RedisServer,
    mongo_url: MongoTarget,
    agents: list[AgentProcess],
    figures: Callable[..., None],
) -> None:
    with FaultProxy(redis_server.port) as redis_link:
        a, b = (ServerProcess(_dir(tmp_path / name)) for name in ("a", "b"))
        for server, url in ((a, f"redis://127.0.0.1:{redis_link.port}/0"), (b, redis_server.url)):
            server.env.update(
                FLEET_MONGO_URL=mongo_url.url, FLEET_DB_NAME=mongo_url.db_name,
                FLEET_REDIS_URL=url, FLEET_STORE_TIMEOUT_MS="1000",
            )  # fmt: skip
        await asyncio.gather(asyncio.to_thread(a.start), asyncio.to_thread(b.start))
        fleet = Fleet(a)
        agent = AgentProcess(
            a, fleet.create_vehicle("usv-r"), "usv-r", tmp_path / "r.db", rate_hz=5
        )
        agent.start()
        agents.append(agent)
        topic = "vehicle/usv-r/telemetry"
        try:
            async with (
                httpx.AsyncClient(timeout=5) as http,
                await connect(a.url, "/ws/client", ADMIN_TOKEN) as on_a,
                await connect(b.url, "/ws/client", ADMIN_TOKEN) as on_b,
            ):
                for ws in (on_a, on_b):
                    assert (await call(ws, "subscribe", "s", topics=[topic]))["ok"]
                for ws in (on_a, on_b):  # both see the vehicle on A live
                    await recv_until(ws, lambda f: f.get("topic") == topic, within_s=20)
                cut = time.monotonic()
                redis_link.refuse(True)
                redis_link.drop()
                await _until(lambda: _is(http, a, "degraded"), 20)
                to_degraded = time.monotonic() - cut
                assert await _status(http, b) == "ok"  # B still has Redis
                # A keeps serving its own sockets: the vehicle's samples reach A's operator
                seen = await recv_until(on_a, lambda f: f.get("topic") == topic, within_s=10)
                before = seen["data"]
                await _drain(on_a)
                fresh = await recv_until(on_a, lambda f: f.get("topic") == topic, within_s=10)
                assert fresh["data"] != before
                stored_during = stored_through(fleet, "usv-r")
                redis_link.refuse(False)
                restored = time.monotonic()
                await _until(lambda: _is(http, a, "ok"), 30)
                # cross-replica delivery resumes: B's operator hears the vehicle on A again
                await _drain(on_b)
                await recv_until(on_b, lambda f: f.get("topic") == topic, within_s=30)
                resumed = time.monotonic() - restored
            through = agent.next_seq() - 1
            wait_until(lambda: has_stored(fleet, "usv-r", through), "samples stored", 30)
            assert stored_during > 0
            assert_exactly_once(fleet, "usv-r", through)
        finally:
            agent.stop()
            await asyncio.gather(asyncio.to_thread(a.stop, 10), asyncio.to_thread(b.stop, 10))
    figures(to_degraded_s=to_degraded, to_resumed_s=resumed)


async def _is(http: httpx.AsyncClient, server: ServerProcess, status: str) -> bool:
    return await _status(http, server) == status


async def _drain(ws: Any) -> None:
    """Drop what the socket already holds (events from before now)."""
    while True:
        try:
            await asyncio.wait_for(ws.recv(), 0.05)
        except TimeoutError:
            return


def _dir(path: Path) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    return path


# ---- the store unreachable ------------------------------------------------------------------


def test_the_store_gone_is_503_with_retry_after_never_a_hang(
    tmp_path: Path,
    make_ferretdb: Callable[[], FerretDB],
    agents: list[AgentProcess],
    figures: Callable[..., None],
) -> None:
    store = make_ferretdb()
    server = ServerProcess(tmp_path)
    server.env.update(
        FLEET_MONGO_URL=store.url, FLEET_DB_NAME="chaos", FLEET_STORE_TIMEOUT_MS="1000"
    )
    server.start()
    fleet = Fleet(server)
    token = fleet.create_vehicle("usv-s")
    agent = AgentProcess(server, token, "usv-s", tmp_path / "s.db", rate_hz=5)
    agent.start()
    agents.append(agent)
    calls = [
        ("GET", "/api/vehicles", {}),
        ("GET", "/api/vehicles/usv-s/telemetry", {}),
        ("POST", "/api/users", {"json": {"username": "late", "role": "viewer"}}),
    ]
    try:
        wait_until(lambda: stored_through(fleet, "usv-s") > 5, "first samples stored")
        down = time.monotonic()
        store.kill()
        answers: list[tuple[str, int, float]] = []

        def refused() -> bool:
            r = httpx.get(f"{server.url}/readyz", timeout=15)
            return r.status_code == 503 and r.headers.get("Retry-After") is not None

        wait_until(refused, "/readyz 503 with Retry-After", 30)
        to_503 = time.monotonic() - down
        for _ in range(int(scaled(2, 10))):
            for method, path, kw in calls:
                started = time.monotonic()
                r = httpx.request(method, f"{server.url}{path}", headers=ADMIN, timeout=15, **kw)
                took = time.monotonic() - started
                answers.append((path, r.status_code, took))
                assert r.status_code == 503, (path, r.status_code, r.text)
                assert r.headers.get("Retry-After"), path
                assert r.json()["error"]["code"] == "unavailable", r.text
        store.start()
        back = time.monotonic()
        wait_until(
            lambda: httpx.get(f"{server.url}/readyz", timeout=15).status_code == 200,
            "ready again",
            60,
        )
        to_ready = time.monotonic() - back
        through = agent.next_seq() - 1
        wait_until(lambda: has_stored(fleet, "usv-s", through), "the backlog stored", 60)
        assert_exactly_once(fleet, "usv-s", through)
    finally:
        agent.stop()
        server.stop(grace_s=10)
    slowest = max(took for _, _, took in answers)
    assert slowest < 10, answers  # an answer, not a hang (the store's timeout is 1 s)
    figures(to_503_s=to_503, slowest_answer_s=slowest, to_ready_s=to_ready)
