"""Two replicas in one process, sharing one store object and a real redis-server.

Each replica is a full server app on its own uvicorn, with its own services,
memory, sweepers and Redis bus; they are built on ONE embedded store object
(``create_app(store=...)``), as two replicas share one MongoDB, and talk
through a real redis-server. Beyond what real replicas share (the store and
Redis) they share only the process and its event loop. What this does not
prove is MongoDB itself (its timing, millisecond datetimes, writes from two
processes racing): the embedded store answers both replicas in one event
loop, so two store calls never run at the same time.
``test_replicas.py::test_command_accepted_on_a_reaches_vehicle_on_b`` runs
on a real MongoDB when FLEET_TEST_MONGO_URL is given.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from datetime import UTC, datetime
from typing import Any

import httpx
import pytest

from server.settings import Settings
from server.storage import open_store
from tests.bus.conftest import RedisServer
from tests.factories import ADMIN, make_user, make_vehicle
from tests.live import call, connect, recv_until, serve

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")

STALE_S = 1.5
OFFLINE_S = 3.0

Replicas = tuple[httpx.AsyncClient, httpx.AsyncClient, str]


@asynccontextmanager
async def two_replicas(
    make_settings: Callable[..., Settings], redis_server: RedisServer, **overrides: Any
) -> AsyncIterator[Replicas]:
    """Replicas A and B on one store; yields an HTTP client to each and B's base URL.
    ``overrides``: settings of both (the presence times too)."""
    times = {"stale_after_s": STALE_S, "offline_after_s": OFFLINE_S}
    settings = make_settings(redis_url=redis_server.url, **{**times, **overrides})
    store = open_store(settings)
    try:
        async with (
            serve(settings, store) as a,
            serve(settings, store) as b,
            httpx.AsyncClient(base_url=a, timeout=10) as api_a,
            httpx.AsyncClient(base_url=b, timeout=10) as api_b,
        ):
            yield api_a, api_b, b
    finally:
        await store.close()


async def _heartbeats(api: httpx.AsyncClient, headers: dict[str, str], instance_id: str) -> None:
    """The vehicle's agent: a heartbeat to its replica every 0.3 s (its cadence, not a wait)."""
    while True:
        r = await api.post("/upper/heartbeat", headers=headers, json={"instance_id": instance_id})
        assert r.status_code == 200, r.text
        await asyncio.sleep(0.3)


async def _presence_events(api: httpx.AsyncClient, vehicle_id: str) -> list[str]:
    r = await api.get(
        "/api/events", headers=ADMIN, params={"vehicle_id": vehicle_id, "kind": "presence"}
    )
    assert r.status_code == 200, r.text
    return [e["data"]["presence"] for e in r.json()["events"]]


async def _until(probe: Callable[[], Any], within_s: float) -> Any:
    """Poll ``probe`` until it returns something true, by a deadline."""
    async with asyncio.timeout(within_s):
        while not (got := await probe()):  # noqa: ASYNC110 (deadline poll)
            await asyncio.sleep(0.05)
    return got


async def _grant(api: httpx.AsyncClient, instance_id: str, user: str) -> None:
    """The admin (field manager) grants ``user`` control for 60 s."""
    r = await api.post(
        "/client/grant_control",
        headers=ADMIN,
        json={"instance_id": instance_id, "user": user, "duration_s": 60},
    )
    assert r.status_code == 200, r.text


async def _submit(
    api: httpx.AsyncClient, headers: dict[str, str], instance_id: str, command: dict[str, Any]
) -> httpx.Response:
    return await api.post(
        "/client/submit_control",
        headers=headers,
        json={"instance_ids": [instance_id], "command": command},
    )


async def test_commands_acks_leases_and_presence_cross_replicas(
    make_settings: Callable[..., Settings], redis_server: RedisServer
) -> None:
    async with two_replicas(make_settings, redis_server) as (api_a, api_b, b):
        vid, vehicle = await make_vehicle(api_a)
        user, operator = await make_user(api_a, "operator", [vid])
        async with await connect(b, "/ws/vehicle", vehicle["Authorization"][7:]) as car:
            ack = await call(
                car, "start_instance", "s", vehicle_id=vid, capabilities=["stop", "go_to"]
            )
            iid = ack["instance_id"]
            started = datetime.fromisoformat(ack["server_time"])
            beating = asyncio.create_task(_heartbeats(api_b, vehicle, iid))
            try:
                # A lease granted on A is honoured by a submit on B.
                await _grant(api_a, iid, user)
                go_to = {"type": "go_to", "args": {"lat": 63.4, "lon": 10.4}}
                r = await _submit(api_b, operator, iid, go_to)
                assert r.status_code == 202, r.text
                pushed = await recv_until(car, lambda f: f["op"] == "command")
                assert pushed["type"] == "go_to"

                # A command accepted on A reaches the vehicle's socket on B, stop first.
                r = await _submit(api_a, operator, iid, {"type": "stop"})
                assert r.status_code == 202, r.text
                stop_id = r.json()["commands"][0]["command_id"]
                pushed = await recv_until(car, lambda f: f["op"] == "command", within_s=10)
                assert (pushed["type"], pushed["command_id"]) == ("stop", stop_id)

                # The vehicle's ack on B is the command's status read on A.
                done = await call(
                    car,
                    "update_fbmessage",
                    "f",
                    instance_id=iid,
                    control_mode="remote",
                    acks=[{"command_id": stop_id, "status": "accepted"}],
                )
                assert done["ok"], done
                r = await api_a.get(f"/api/commands/{stop_id}", headers=operator)
                assert r.status_code == 200 and r.json()["status"] == "accepted", r.text
                r = await api_a.get(
                    "/client/get_fbmessage", headers=operator, params={"instance_id": iid}
                )
                statuses = {c["command_id"]: c["status"] for c in r.json()["commands"]}
                assert statuses[stop_id] == "accepted"

                # Revoked on A: B refuses the former holder at once.
                r = await api_a.post(
                    "/client/revoke_control", headers=ADMIN, json={"instance_id": iid}
                )
                assert r.status_code == 200, r.text
                r = await _submit(api_b, operator, iid, go_to)
                assert r.status_code == 409 and r.json()["error"]["code"] == "control_not_held"

                # In contact with B only, for well past offline_after_s: A never marks it lost.
                async def long_enough() -> bool:
                    r = await api_b.post(
                        "/client/connect_instance", headers=ADMIN, json={"instance_id": iid}
                    )
                    seen = datetime.fromisoformat(r.json()["instance"]["last_seen"])
                    return (seen - started).total_seconds() > 2 * OFFLINE_S

                await _until(long_enough, within_s=20)
                assert set(await _presence_events(api_a, vid)) <= {"online"}
                r = await api_a.get("/api/vehicles", headers=ADMIN)
                (view,) = [v for v in r.json()["vehicles"] if v["vehicle_id"] == vid]
                assert view["presence"] == "online"
            finally:
                beating.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await beating

        # Silent now: it goes stale, then offline, each told once whichever replica saw it.
        async def offline() -> list[str] | None:
            seen = await _presence_events(api_a, vid)
            return seen if "offline" in seen else None

        seen = await _until(offline, within_s=20)
        assert seen.count("stale") == 1 and seen.count("offline") == 1, seen


@pytest.mark.parametrize("where", ["a", "b"])
async def test_a_vehicle_started_on_one_replica_resumes_on_the_other(
    make_settings: Callable[..., Settings], redis_server: RedisServer, where: str
) -> None:
    async with two_replicas(make_settings, redis_server) as (api_a, api_b, _):
        vid, vehicle = await make_vehicle(api_a)
        body = {"vehicle_id": vid, "capabilities": ["stop"]}
        first = await api_a.post("/upper/start_instance", headers=vehicle, json=body)
        again = await (api_a if where == "a" else api_b).post(
            "/upper/start_instance", headers=vehicle, json=body
        )
        assert again.json()["instance_id"] == first.json()["instance_id"]
        assert again.json()["resumed"] is True
        r = await api_b.post(
            "/upper/finish_instance",
            headers=vehicle,
            json={"instance_id": again.json()["instance_id"]},
        )
        assert r.status_code == 200, r.text
        fresh = await api_a.post("/upper/start_instance", headers=vehicle, json=body)
        assert fresh.json()["resumed"] is False
        assert fresh.json()["instance_id"] != first.json()["instance_id"]


async def test_a_long_poll_on_one_replica_gets_a_command_accepted_on_the_other(
    make_settings: Callable[..., Settings], redis_server: RedisServer
) -> None:
    # One long poll per vehicle: a second one is refused while the first waits (429).
    async with two_replicas(make_settings, redis_server, long_poll_max=1) as (api_a, api_b, _):
        vid, vehicle = await make_vehicle(api_a)
        _, operator = await make_user(api_a, "operator", [vid])
        r = await api_b.post(
            "/upper/start_instance", headers=vehicle, json={"vehicle_id": vid, "capabilities": []}
        )
        iid = r.json()["instance_id"]

        def start_poll() -> asyncio.Task[httpx.Response]:
            params = {"instance_id": iid, "wait_s": 20}
            return asyncio.create_task(
                api_b.get("/upper/get_control", headers=vehicle, params=params, timeout=30)
            )

        poll = start_poll()

        async def waiting_on_b() -> bool:
            """Whether the poll is open on B: a second one is refused (429) while it is."""
            nonlocal poll
            if poll.done():  # refused while this probe held the one slot: open it again
                assert poll.result().status_code == 429, poll.result().text
                poll = start_poll()
                return False
            params = {"instance_id": iid, "wait_s": 0.05}
            r = await api_b.get("/upper/get_control", headers=vehicle, params=params)
            return r.status_code == 429

        await _until(waiting_on_b, within_s=10)
        r = await _submit(api_a, operator, iid, {"type": "stop"})
        assert r.status_code == 202, r.text
        async with asyncio.timeout(10):  # well before the poll's own 20 s
            got = await poll
        assert [c["type"] for c in got.json()["commands"]] == ["stop"]
        # Cancelled on A once delivered on B: the vehicle hears "abort" on its next report.
        command_id = got.json()["commands"][0]["command_id"]
        r = await api_a.post(
            "/client/cancel_command", headers=operator, json={"command_id": command_id}
        )
        assert r.status_code == 200 and r.json()["status"] == "cancelled", r.text
        r = await api_b.post(
            "/upper/update_fbmessage",
            headers=vehicle,
            json={"instance_id": iid, "acks": [{"command_id": command_id, "status": "accepted"}]},
        )
        assert command_id in r.json()["abort"]
        r = await api_b.get(f"/api/commands/{command_id}", headers=operator)
        assert r.json()["status"] == "cancelled"


async def test_a_long_poll_open_on_one_replica_keeps_the_vehicle_online_on_the_other(
    make_settings: Callable[..., Settings], redis_server: RedisServer
) -> None:
    async with two_replicas(make_settings, redis_server) as (api_a, api_b, _):
        vid, vehicle = await make_vehicle(api_a)
        r = await api_a.post(
            "/upper/start_instance", headers=vehicle, json={"vehicle_id": vid, "capabilities": []}
        )
        iid = r.json()["instance_id"]
        # Its only contact for twice offline_after_s: one long poll on B.
        params = {"instance_id": iid, "wait_s": 2 * OFFLINE_S}
        r = await api_b.get("/upper/get_control", headers=vehicle, params=params, timeout=30)
        assert r.status_code == 200 and r.json()["commands"] == []
        assert set(await _presence_events(api_a, vid)) <= {"online"}


async def test_redis_away_each_replica_serves_its_own_and_catches_up_after(
    make_settings: Callable[..., Settings], redis_server: RedisServer
) -> None:
    async with two_replicas(make_settings, redis_server) as (api_a, api_b, b):
        vid, vehicle = await make_vehicle(api_a)
        user, operator = await make_user(api_a, "operator", [vid])
        async with await connect(b, "/ws/vehicle", vehicle["Authorization"][7:]) as car:
            ack = await call(car, "start_instance", "s", vehicle_id=vid, capabilities=["go_to"])
            iid = ack["instance_id"]
            redis_server.stop()

            async def both_cut_off() -> bool:
                ready = [(await api.get("/readyz")) for api in (api_a, api_b)]
                seen = [(r.status_code, r.json()["status"]) for r in ready]
                return seen == [(200, "degraded"), (200, "degraded")]

            await _until(both_cut_off, within_s=20)
            # Decisions still come from the store: a lease granted on A holds on B.
            await _grant(api_a, iid, user)
            go_to = {"type": "go_to", "args": {"lat": 63.4, "lon": 10.4}}
            r = await _submit(api_b, operator, iid, go_to)
            assert r.status_code == 202, r.text  # B's own socket: pushed at once
            assert (await recv_until(car, lambda f: f["op"] == "command"))["type"] == "go_to"
            r = await _submit(api_a, operator, iid, {"type": "stop"})
            assert r.status_code == 202, r.text
            stop_id = r.json()["commands"][0]["command_id"]
            redis_server.start()
            # Redis back: the stop accepted on A while B was cut off reaches B's socket.
            pushed = await recv_until(car, lambda f: f["op"] == "command", within_s=20)
            assert pushed["command_id"] == stop_id


async def _sailing(
    api: httpx.AsyncClient, headers: dict[str, str], instance_id: str, course: dict[str, float]
) -> None:
    """The vehicle's agent: its position and course to its replica every 0.3 s."""
    seq = 0
    while True:
        seq += 1
        sample = {"seq": seq, "ts": datetime.now(UTC).isoformat(), **course}
        r = await api.post(
            "/upper/update_param",
            headers=headers,
            json={"instance_id": instance_id, "samples": [sample]},
        )
        assert r.status_code == 200, r.text
        await asyncio.sleep(0.3)


async def test_the_collision_forecast_sees_the_vehicles_of_both_replicas(
    make_settings: Callable[..., Settings], redis_server: RedisServer
) -> None:
    """One replica forecasts for all: two vehicles heading at each other, each on its own
    replica, raise the risk on both (the other replica's course read from the store)."""
    forecast = {"separation_m": 10.0, "forecast_s": 60.0, "forecast_every_s": 0.2}
    async with two_replicas(make_settings, redis_server, **forecast) as (api_a, api_b, _):
        courses = {
            "a": {"lat": 43.0, "lon": 15.0, "speed_mps": 5.0, "heading_deg": 90.0},
            "b": {"lat": 43.0, "lon": 15.001, "speed_mps": 5.0, "heading_deg": 270.0},
        }
        agents = []
        vehicles = {}
        for name, api in (("a", api_a), ("b", api_b)):
            vid, vehicle = await make_vehicle(api_a)
            r = await api.post(
                "/upper/start_instance",
                headers=vehicle,
                json={"vehicle_id": vid, "capabilities": ["stop"]},
            )
            instance_id = r.json()["instance_id"]
            vehicles[name] = vid
            agents.append(asyncio.create_task(_sailing(api, vehicle, instance_id, courses[name])))

        async def risks() -> list[str] | None:
            found = []
            for vid in vehicles.values():
                r = await api_a.get(
                    "/api/events",
                    headers=ADMIN,
                    params={"vehicle_id": vid, "kind": "collision_risk"},
                )
                assert r.status_code == 200, r.text
                found += [e["data"]["other_vehicle_id"] for e in r.json()["events"]]
            return found if len(set(found)) == 2 else None

        try:
            seen = await _until(risks, within_s=15)
        finally:
            for agent in agents:
                agent.cancel()
            await asyncio.gather(*agents, return_exceptions=True)
        assert set(seen) == set(vehicles.values())
