"""The harbour the safety tests sail in, end to end: the server in process, real agents
with simulated vehicles talking to it over HTTP (the agent's own transport on the app's
ASGI interface), and a link that the test cuts and mends. Used by
``test_failsafe_e2e.py``, ``test_lease_end_e2e.py``, ``test_whole_plans_e2e.py`` and
``test_zone_collision_e2e.py``; the ``harbour`` fixture is in ``conftest.py``.

Every wait is a deadline on a condition; the positions judged are the telemetry the
server stored.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
from asgi_lifespan import LifespanManager

from server.app import create_app
from server.settings import Settings
from tests.factories import ADMIN
from vehicle_client.adapters.sim import SimAdapter
from vehicle_client.agent import AgentConfig, VehicleAgent
from vehicle_client.backoff import Backoff
from vehicle_client.outbox import Outbox
from vehicle_client.sim import Current
from vehicle_client.transport.http import HttpTransport

START = (43.94, 15.44)
DEADLINE_S = 30.0


class Link(httpx.AsyncBaseTransport):
    """The vehicle's link: the app's ASGI interface, which the test may cut (every call
    fails as a refused connection) or tamper with (a hook rewrites what comes back)."""

    def __init__(self, inner: httpx.AsyncBaseTransport) -> None:
        self.inner = inner
        self.cut = False
        self.rewrite: Callable[[str, dict[str, Any]], dict[str, Any]] | None = None

    async def handle_async_request(self, request: httpx.Request) -> httpx.Response:
        if self.cut:
            raise httpx.ConnectError("the link is cut", request=request)
        response = await self.inner.handle_async_request(request)
        if self.rewrite is None or response.status_code != 200:
            return response
        body = json.loads(await response.aread())
        body = self.rewrite(request.url.path, body)
        return httpx.Response(200, json=body, request=request)


@dataclass
class Boat:
    vehicle_id: str
    agent: VehicleAgent
    link: Link

    @property
    def instance_id(self) -> str:
        assert self.agent.instance_id is not None
        return self.agent.instance_id

    def at(self, east: float, north: float) -> dict[str, float]:
        lat, lon = self.agent.adapter.sim.frame.to_latlon(east, north)  # type: ignore[attr-defined]
        return {"lat": lat, "lon": lon}

    def enu(self, p: dict[str, Any]) -> tuple[float, float]:
        frame = self.agent.adapter.sim.frame  # type: ignore[attr-defined]
        east, north = frame.to_enu(p["lat"], p["lon"])
        return float(east), float(north)

    @property
    def sim_s(self) -> float:
        return float(self.agent.adapter.sim.elapsed_s)  # type: ignore[attr-defined]


class Harbour:
    """The server, its admin's HTTP client, and the boats started in it."""

    def __init__(self, app: Any, http: httpx.AsyncClient, tmp_path: Path) -> None:
        self.app = app
        self.http = http
        self.tmp_path = tmp_path
        self.tasks: list[asyncio.Task[None]] = []
        self.boats: list[Boat] = []

    async def call(self, method: str, path: str, who: dict[str, str] = ADMIN, **kw: Any) -> Any:
        r = await self.http.request(method, path, headers=who, **kw)
        assert r.is_success, (method, path, r.status_code, r.text)
        return r.json()

    async def boat(
        self,
        vehicle_id: str,
        *,
        start: tuple[float, float] = START,
        current: Current | None = None,
        failsafe: dict[str, Any] | None = None,
        time_scale: float = 40.0,
        vehicle_type: str | None = None,
    ) -> Boat:
        made = {"vehicle_id": vehicle_id} | ({"vehicle_type": vehicle_type} if vehicle_type else {})
        token = (await self.call("POST", "/api/vehicles", json=made))["token"]
        if failsafe is not None:
            await self.call("PUT", f"/api/vehicles/{vehicle_id}/failsafe", json=failsafe)
        link = Link(httpx.ASGITransport(app=self.app))
        transport = HttpTransport("http://fleet.test", token, transport=link)
        adapter = SimAdapter(*start, time_scale=time_scale, current=current)
        config = AgentConfig(vehicle_id=vehicle_id, rate_hz=10.0, poll_wait_s=1.0, tick_s=0.05)
        outbox = Outbox(self.tmp_path / f"{vehicle_id}.db")
        agent = VehicleAgent(config, adapter, transport, outbox, backoff=Backoff(0.05, 0.2))
        self.tasks.append(asyncio.create_task(agent.run()))
        boat = Boat(vehicle_id, agent, link)
        self.boats.append(boat)
        await until(lambda: agent.instance_id is not None, "the instance started")
        await until_async(lambda: self._positioned(boat), "a first position stored")
        return boat

    async def _positioned(self, boat: Boat) -> bool:
        view = await self.call("GET", f"/api/vehicles/{boat.vehicle_id}")
        return view.get("position") is not None

    async def operator(self, *boats: Boat, operator_timeout_s: int | None = None) -> dict:
        name = f"op-{len(self.boats)}-{boats[0].vehicle_id}"
        made = await self.call(
            "POST",
            "/api/users",
            json={"username": name, "role": "operator", "vehicles": [b.vehicle_id for b in boats]},
        )
        for b in boats:
            body: dict[str, Any] = {"instance_id": b.instance_id, "user": name, "duration_s": 600}
            if operator_timeout_s is not None:
                body["operator_timeout_s"] = operator_timeout_s
            await self.call("POST", "/client/grant_control", json=body)
        return {"Authorization": f"Bearer {made['token']}"}

    async def submit(self, who: dict[str, str], boat: Boat, kind: str, args: dict) -> str:
        body = {"instance_ids": [boat.instance_id], "command": {"type": kind, "args": args}}
        r = await self.call("POST", "/client/submit_control", who, json=body)
        command_id: str = r["commands"][0]["command_id"]
        return command_id

    async def try_submit(
        self, who: dict[str, str], boat: Boat, kind: str, args: dict
    ) -> httpx.Response:
        """Submit as ``who``: the server's answer as it is, a refusal too."""
        body = {"instance_ids": [boat.instance_id], "command": {"type": kind, "args": args}}
        return await self.http.post("/client/submit_control", headers=who, json=body)

    async def command(self, command_id: str) -> dict[str, Any]:
        result: dict[str, Any] = await self.call("GET", f"/api/commands/{command_id}")
        return result

    async def events(self, boat: Boat, kind: str) -> list[dict[str, Any]]:
        params = {"vehicle_id": boat.vehicle_id, "kind": kind}
        found: list[dict[str, Any]] = (await self.call("GET", "/api/events", params=params))[
            "events"
        ]
        return found

    async def telemetry(self, boat: Boat) -> list[dict[str, Any]]:
        samples: list[dict[str, Any]] = []
        after = -1
        while True:
            page = await self.call(
                "GET",
                f"/api/vehicles/{boat.vehicle_id}/telemetry",
                params={"after_seq": after, "limit": 1000},
            )
            samples += page["samples"]
            if len(page["samples"]) < 1000:
                return samples
            after = page["samples"][-1]["seq"]

    async def position(self, boat: Boat) -> tuple[float, float]:
        view = await self.call("GET", f"/api/vehicles/{boat.vehicle_id}")
        return boat.enu(view["position"])


@asynccontextmanager
async def in_process(settings: Settings) -> AsyncIterator[tuple[Any, httpx.AsyncClient]]:
    """The app on ``settings``, started in process, and an HTTP client to it through its
    ASGI interface (``http://fleet.test``)."""
    app = create_app(settings)
    async with LifespanManager(app) as manager:
        transport = httpx.ASGITransport(app=manager.app)
        async with httpx.AsyncClient(transport=transport, base_url="http://fleet.test") as http:
            yield manager.app, http


async def until(check: Callable[[], bool], what: str, within_s: float = DEADLINE_S) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + within_s
    while not check():
        assert loop.time() < deadline, f"gave up waiting: {what}"
        await asyncio.sleep(0.02)


async def until_async(check: Callable[[], Any], what: str, within_s: float = DEADLINE_S) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + within_s
    while not await check():
        assert loop.time() < deadline, f"gave up waiting: {what}"
        await asyncio.sleep(0.05)


async def sail_east(h: Harbour, boat: Boat, who: dict[str, str], reach_m: float = 40.0) -> str:
    """Send the boat 2 km east and wait until it is ``reach_m`` on its way."""
    command_id = await h.submit(who, boat, "go_to", boat.at(2000.0, 0.0))
    await until_async(
        lambda: _east_of(h, boat, reach_m), f"{boat.vehicle_id} {reach_m} m on its way"
    )
    return command_id


async def _east_of(h: Harbour, boat: Boat, metres: float) -> bool:
    return (await h.position(boat))[0] >= metres


DRIFT = Current(east_mps=0.0, north_mps=0.1)  # pushes north: keep_station holds against it


async def held_within(h: Harbour, boat: Boat, metres: float, sim_seconds: float) -> None:
    """Over ``sim_seconds`` of the boat's time, every stored position stays within
    ``metres`` of the first."""
    first = await h.position(boat)
    begun = boat.sim_s
    worst = 0.0
    while boat.sim_s < begun + sim_seconds:
        e, n = await h.position(boat)
        worst = max(worst, ((e - first[0]) ** 2 + (n - first[1]) ** 2) ** 0.5)
        await asyncio.sleep(0.05)
    assert worst <= metres, f"moved {worst:.1f} m while holding"
