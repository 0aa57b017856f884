"""A small world for command and control tests: an app, vehicles, people, leases.

Everything goes through HTTP; the clock is the test's (``FakeClock``).
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass
from typing import Any

import httpx
from asgi_lifespan import LifespanManager
from fastapi import FastAPI

from server.app import create_app
from server.settings import Settings
from tests.factories import ADMIN, FakeClock, make_user, make_vehicle, sample, start_instance

ALL_CAPABILITIES = ["stop", "go_to", "keep_station", "follow_path"]
GO_TO = {"type": "go_to", "args": {"lat": 43.95, "lon": 15.45}}
STOP = {"type": "stop", "args": {}}
KEEP = {"type": "keep_station", "args": {}}


@dataclass
class Vehicle:
    vehicle_id: str
    headers: dict[str, str]
    instance_id: str


@dataclass
class Person:
    username: str
    headers: dict[str, str]


@dataclass
class World:
    http: httpx.AsyncClient
    clock: FakeClock
    app: FastAPI

    async def vehicle(self, capabilities: list[str] | None = None) -> Vehicle:
        vehicle_id, headers = await make_vehicle(self.http)
        started = await start_instance(
            self.http,
            vehicle_id,
            headers,
            capabilities=ALL_CAPABILITIES if capabilities is None else capabilities,
        )
        return Vehicle(vehicle_id, headers, started["instance_id"])

    async def person(self, role: str, *vehicles: Vehicle) -> Person:
        username, headers = await make_user(self.http, role, [v.vehicle_id for v in vehicles])
        return Person(username, headers)

    async def operator_in_control(self, vehicle: Vehicle, duration_s: int = 600) -> Person:
        op = await self.person("operator", vehicle)
        r = await self.grant(vehicle, op.username, duration_s=duration_s)
        assert r.status_code == 200, r.text
        return op

    async def client_post(self, path: str, headers: dict[str, str], **body: Any) -> httpx.Response:
        """``POST /client/<path>`` with ``body`` as JSON."""
        return await self.http.post(f"/client/{path}", headers=headers, json=body)

    async def grant(
        self, vehicle: Vehicle, username: str, *, duration_s: int = 600, by: dict[str, str] = ADMIN
    ) -> httpx.Response:
        return await self.http.post(
            "/client/grant_control",
            headers=by,
            json={"instance_id": vehicle.instance_id, "user": username, "duration_s": duration_s},
        )

    async def submit(
        self,
        who: Person | dict[str, str],
        targets: list[Vehicle] | list[str],
        command: dict[str, Any],
        ttl_s: int = 30,
    ) -> httpx.Response:
        ids = [t.instance_id if isinstance(t, Vehicle) else t for t in targets]
        return await self.http.post(
            "/client/submit_control",
            headers=_headers(who),
            json={"instance_ids": ids, "command": command, "ttl_s": ttl_s},
        )

    async def queued(
        self, who: Person, vehicle: Vehicle, command: dict[str, Any], ttl_s: int = 30
    ) -> str:
        r = await self.submit(who, [vehicle], command, ttl_s=ttl_s)
        assert r.status_code == 202, r.text
        command_id: str = r.json()["commands"][0]["command_id"]
        return command_id

    async def poll(self, vehicle: Vehicle, wait_s: float = 0) -> list[dict[str, Any]]:
        commands: list[dict[str, Any]] = (await self.poll_answer(vehicle, wait_s))["commands"]
        return commands

    def long_poll(self, vehicle: Vehicle, wait_s: float = 30) -> asyncio.Task[dict[str, Any]]:
        """A long ``get_control`` opened in the background; await :meth:`poll_open` before
        acting on what it is to hear."""
        return asyncio.create_task(self.poll_answer(vehicle, wait_s))

    async def poll_open(self, vehicle: Vehicle) -> None:
        """Wait until the server holds a long poll of ``vehicle`` open."""
        state = self.services.instances.current(vehicle.vehicle_id)
        assert state is not None

        async def polling() -> bool:
            return bool(state.polling)

        await eventually(polling)

    async def poll_answer(self, vehicle: Vehicle, wait_s: float = 0) -> dict[str, Any]:
        """``get_control``'s whole answer (``commands``, ``abort``, ``failsafe``)."""
        r = await self.http.get(
            "/upper/get_control",
            headers=vehicle.headers,
            params={"instance_id": vehicle.instance_id, "wait_s": wait_s},
        )
        assert r.status_code == 200, r.text
        answer: dict[str, Any] = r.json()
        return answer

    async def ack(
        self, vehicle: Vehicle, *acks: tuple[str, str], control_mode: str | None = None
    ) -> dict[str, Any]:
        body: dict[str, Any] = {
            "instance_id": vehicle.instance_id,
            "acks": [{"command_id": c, "status": s} for c, s in acks],
        }
        if control_mode is not None:
            body["control_mode"] = control_mode
        r = await self.http.post("/upper/update_fbmessage", headers=vehicle.headers, json=body)
        assert r.status_code == 200, r.text
        result: dict[str, Any] = r.json()
        return result

    async def command(self, command_id: str) -> dict[str, Any]:
        r = await self.http.get(f"/api/commands/{command_id}", headers=ADMIN)
        assert r.status_code == 200, r.text
        result: dict[str, Any] = r.json()
        return result

    async def move_to(self, vehicle: Vehicle, seq: int, lat: float, lon: float) -> None:
        r = await self.http.post(
            "/upper/update_param",
            headers=vehicle.headers,
            json={
                "instance_id": vehicle.instance_id,
                "samples": [sample(seq, ts=self.clock(), lat=lat, lon=lon)],
            },
        )
        assert r.status_code == 200, r.text

    @property
    def services(self) -> Any:
        return self.app.state.services


def _headers(who: Person | dict[str, str]) -> dict[str, str]:
    return who.headers if isinstance(who, Person) else who


@asynccontextmanager
async def world(settings: Settings, clock: FakeClock | None = None) -> AsyncIterator[World]:
    clock = clock or FakeClock()
    app = create_app(settings, clock=clock)
    # A stop may wait for a background pass under way on a loaded machine (FerretDB
    # beside the browsers of CI): past asgi-lifespan's 5 s, twice; a hang still fails.
    async with LifespanManager(app, shutdown_timeout=30) as manager:
        transport = httpx.ASGITransport(app=manager.app)
        async with httpx.AsyncClient(transport=transport, base_url="http://test") as http:
            yield World(http, clock, app)


async def eventually(check: Callable[[], Awaitable[bool]], timeout_s: float = 5.0) -> None:
    """Wait for ``check`` to hold, up to a deadline (background tasks act on their own beat)."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout_s
    while not await check():
        assert loop.time() < deadline, "the condition did not hold before the deadline"
        await asyncio.sleep(0.02)


def statuses(command: dict[str, Any]) -> list[str]:
    return [h["status"] for h in command["history"]]
