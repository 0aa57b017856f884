"""Commands the vehicle and the server must agree on. A command cancelled while the boat
carries it out stops the boat at once. A vehicle's agent that starts again tells the
server what it still has in hand: a command it was carrying out when its computer was
replaced (its outbox, and with it the commands it had seen, gone) ends ``failed`` instead
of ``executing`` for ever, and one it still carries out after a lost link is left alone.

The server in process, real agents with simulated vehicles over HTTP on the app's ASGI
interface; every wait is a deadline on a condition.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import httpx
import pytest

from server.settings import Settings
from tests.agent.harbour import in_process
from tests.factories import ADMIN
from tests.live import serve
from vehicle_client.adapters.sim import SimAdapter
from vehicle_client.agent import AgentConfig, VehicleAgent
from vehicle_client.backoff import Backoff
from vehicle_client.outbox import Outbox
from vehicle_client.transport.http import HttpTransport
from vehicle_client.transport.ws import WsLink

START = (43.94, 15.44)
FAR_EAST = {"lat": 43.94, "lon": 15.50}  # about 5 km: the boat is still on its way
DEADLINE_S = 30.0


class Cuttable(httpx.AsyncBaseTransport):
    def __init__(self, inner: httpx.AsyncBaseTransport) -> None:
        self.inner, self.cut = inner, False

    async def handle_async_request(self, request: httpx.Request) -> httpx.Response:
        if self.cut:
            raise httpx.ConnectError("the link is cut", request=request)
        return await self.inner.handle_async_request(request)


async def until(check: Callable[[], Any], what: str) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + DEADLINE_S
    while not await check():
        assert loop.time() < deadline, f"gave up waiting: {what}"
        await asyncio.sleep(0.05)


class Field:
    def __init__(self, app: Any, http: httpx.AsyncClient, tmp_path: Path) -> None:
        self.app, self.http, self.tmp_path = app, http, tmp_path
        self.running: list[tuple[asyncio.Task[None], VehicleAgent]] = []

    async def call(self, method: str, path: str, **kw: Any) -> Any:
        r = await self.http.request(method, path, headers=ADMIN, **kw)
        assert r.is_success, (method, path, r.status_code, r.text)
        return r.json()

    async def agent(self, token: str, outbox: str) -> tuple[VehicleAgent, Cuttable]:
        link = Cuttable(httpx.ASGITransport(app=self.app))
        agent = VehicleAgent(
            AgentConfig(vehicle_id="usv-r", rate_hz=5.0, poll_wait_s=1.0, tick_s=0.05),
            SimAdapter(*START, time_scale=5.0),
            HttpTransport("http://fleet.test", token, transport=link),
            Outbox(self.tmp_path / outbox),
            backoff=Backoff(0.05, 0.2),
        )
        task = asyncio.create_task(agent.run())
        self.running.append((task, agent))
        await until(self._started(agent), "the instance started")
        return agent, link

    @staticmethod
    def _started(agent: VehicleAgent) -> Callable[[], Any]:
        async def check() -> bool:
            return agent.stats.connected

        return check

    async def stop(self, agent: VehicleAgent) -> None:
        for task, one in self.running:
            if one is agent:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
                agent.outbox.close()
        self.running = [(t, a) for t, a in self.running if a is not agent]

    async def go_far(self, instance_id: str) -> str:
        body = {"instance_ids": [instance_id], "command": {"type": "go_to", "args": FAR_EAST}}
        r = await self.call("POST", "/client/submit_control", json=body)
        command_id: str = r["commands"][0]["command_id"]
        await until(self.status_is(command_id, "executing"), "the go_to under way")
        return command_id

    def status_is(self, command_id: str, status: str) -> Callable[[], Any]:
        async def check() -> bool:
            return bool((await self.call("GET", f"/api/commands/{command_id}"))["status"] == status)

        return check


@pytest.fixture
async def field(make_settings: Callable[..., Settings], tmp_path: Path) -> AsyncIterator[Field]:
    async with in_process(make_settings(heartbeat_interval_s=0.5)) as (app, http):
        f = Field(app, http, tmp_path)
        try:
            yield f
        finally:
            for task, agent in f.running:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await task
                agent.outbox.close()


async def _grant_admin(f: Field, instance_id: str) -> None:
    body = {"instance_id": instance_id, "user": "admin", "duration_s": 600}
    await f.call("POST", "/client/grant_control", json=body)


async def test_a_command_lost_with_the_agents_disk_ends_failed(field: Field) -> None:
    f = field
    token = (await f.call("POST", "/api/vehicles", json={"vehicle_id": "usv-r"}))["token"]
    first, _ = await f.agent(token, "first.db")
    instance_id = first.instance_id
    assert instance_id is not None
    await _grant_admin(f, instance_id)
    command_id = await f.go_far(instance_id)
    await f.stop(first)  # the computer is replaced: a new disk, nothing remembered

    second, _ = await f.agent(token, "second.db")
    assert second.instance_id == instance_id  # the instance resumed
    await until(f.status_is(command_id, "failed"), "the lost go_to failed")
    cmd = await f.call("GET", f"/api/commands/{command_id}")
    assert "the vehicle resumed without it" in cmd["history"][-1]["detail"]
    # The vehicle takes commands as before.
    again = await f.go_far(instance_id)
    assert again != command_id


async def test_a_command_carried_on_through_a_lost_link_is_left_alone(field: Field) -> None:
    f = field
    token = (await f.call("POST", "/api/vehicles", json={"vehicle_id": "usv-r"}))["token"]
    await f.call(
        "PUT", "/api/vehicles/usv-r/failsafe", json={"action": "none", "after_s": 1}
    )  # on a lost link the boat carries on with its command
    agent, link = await f.agent(token, "only.db")
    assert agent.instance_id is not None
    await _grant_admin(f, agent.instance_id)
    command_id = await f.go_far(agent.instance_id)
    sessions = agent.stats.sessions
    link.cut = True

    async def lost() -> bool:
        return not agent.stats.connected

    await until(lost, "the agent to find the link down")
    link.cut = False

    async def back() -> bool:
        return agent.stats.sessions > sessions and agent.stats.connected

    await until(back, "a new session")
    cmd = await f.call("GET", f"/api/commands/{command_id}")
    assert cmd["status"] == "executing", cmd["history"]
    assert agent.helm.pilot.active_id == command_id


async def test_a_go_to_cancelled_under_way_stops_the_boat(field: Field) -> None:
    """A go_to sends no ack while it runs: the cancel reaches the boat through its long
    poll, and the boat gives up the target (the simulator's task ends, the pilot is idle)."""
    f = field
    token = (await f.call("POST", "/api/vehicles", json={"vehicle_id": "usv-r"}))["token"]
    agent, _ = await f.agent(token, "cancel.db")
    assert agent.instance_id is not None
    await _grant_admin(f, agent.instance_id)
    command_id = await f.go_far(agent.instance_id)
    sim = agent.adapter.sim  # type: ignore[attr-defined]
    assert sim.task is not None and agent.helm.pilot.active_id == command_id

    async def acks_answered() -> bool:  # its last update_fbmessage came back: none follows
        return not agent.helm.acks and agent.helm.sent_mode == "remote"

    await until(acks_answered, "the agent's acks answered")

    cancelled = await f.call("POST", "/client/cancel_command", json={"command_id": command_id})
    assert cancelled["status"] == "cancelled"

    async def halted() -> bool:
        return sim.task is None and agent.helm.pilot.active_id is None

    await until(halted, "the boat to give up the cancelled go_to")
    assert agent.helm.pilot.control_mode == "idle"


async def test_over_the_socket_a_go_to_cancelled_under_way_stops_the_boat(
    make_settings: Callable[..., Settings], tmp_path: Path
) -> None:
    """The same over a WebSocket: the server pushes ``abort`` the moment the cancel lands."""
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as http:
        f = Field(None, http, tmp_path)
        token = (await f.call("POST", "/api/vehicles", json={"vehicle_id": "usv-r"}))["token"]
        link = WsLink(base, token)
        agent = VehicleAgent(
            AgentConfig(vehicle_id="usv-r", rate_hz=5.0, tick_s=0.05),
            SimAdapter(*START, time_scale=5.0),
            link.vehicle("usv-r"),
            Outbox(tmp_path / "ws.db"),
            backoff=Backoff(0.05, 0.2),
        )
        task = asyncio.create_task(agent.run())
        try:
            await until(Field._started(agent), "the instance started over the socket")
            assert agent.link_kind == "ws" and agent.instance_id is not None
            await _grant_admin(f, agent.instance_id)
            command_id = await f.go_far(agent.instance_id)
            sim = agent.adapter.sim  # type: ignore[attr-defined]

            async def acks_answered() -> bool:
                return not agent.helm.acks and agent.helm.sent_mode == "remote"

            await until(acks_answered, "the agent's acks answered")
            await f.call("POST", "/client/cancel_command", json={"command_id": command_id})

            async def halted() -> bool:
                return sim.task is None and agent.helm.pilot.active_id is None

            await until(halted, "the boat to give up the cancelled go_to")
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
            agent.outbox.close()
            await link.aclose()
