"""Missions a field team can trust, end to end: the server in process, real agents with
simulated vehicles talking to it over HTTP (the agent's own transport on the app's ASGI
interface), and a link that the test cuts and mends.

Every wait is a deadline on a condition; the positions judged are the telemetry the
server stored.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
from asgi_lifespan import LifespanManager

from fleet_protocol import parse_ts
from server.app import create_app
from server.settings import Settings
from tests.factories import ADMIN
from vehicle_client.adapters.sim import SimAdapter
from vehicle_client.agent import AgentConfig, VehicleAgent
from vehicle_client.backoff import Backoff
from vehicle_client.geo import distance_m
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
    ) -> Boat:
        token = (await self.call("POST", "/api/vehicles", json={"vehicle_id": vehicle_id}))["token"]
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


@pytest.fixture
async def harbour(make_settings: Callable[..., Settings], tmp_path: Path) -> AsyncIterator[Harbour]:
    settings = make_settings(
        separation_m=10.0, forecast_s=60.0, forecast_every_s=0.2, heartbeat_interval_s=0.5
    )
    app = create_app(settings)
    async with LifespanManager(app) as manager:
        transport = httpx.ASGITransport(app=manager.app)
        async with httpx.AsyncClient(transport=transport, base_url="http://fleet.test") as http:
            h = Harbour(manager.app, http, tmp_path)
            try:
                yield h
            finally:
                for task in h.tasks:
                    task.cancel()
                for task in h.tasks:
                    with contextlib.suppress(asyncio.CancelledError, Exception):
                        await task
                for boat in h.boats:
                    boat.agent.outbox.close()


async def sail_east(h: Harbour, boat: Boat, who: dict[str, str], reach_m: float = 40.0) -> str:
    """Send the boat 2 km east and wait until it is ``reach_m`` on its way."""
    command_id = await h.submit(who, boat, "go_to", boat.at(2000.0, 0.0))
    await until_async(
        lambda: _east_of(h, boat, reach_m), f"{boat.vehicle_id} {reach_m} m on its way"
    )
    return command_id


async def _east_of(h: Harbour, boat: Boat, metres: float) -> bool:
    return (await h.position(boat))[0] >= metres


# ---- the failsafe after a cut link ----------------------------------------------------------

DRIFT = Current(east_mps=0.0, north_mps=0.1)  # pushes north: keep_station holds against it


async def cut_and_mend(h: Harbour, boat: Boat, sim_seconds: float) -> tuple[float, float]:
    """Cut the boat's link, let ``sim_seconds`` of its time pass once its failsafe time
    is up, mend the link; the boat's local position when the failsafe time was up."""
    boat.link.cut = True
    await until(lambda: boat.agent.helm.link.lost, "the agent to find the link lost")
    engaged_at = boat.agent.adapter.sim.position  # type: ignore[attr-defined]
    begun = boat.sim_s
    await until(lambda: boat.sim_s >= begun + sim_seconds, f"{sim_seconds} s of the boat's time")
    boat.link.cut = False
    return boat.enu({"lat": engaged_at[0], "lon": engaged_at[1]})


async def stored_after(h: Harbour, boat: Boat, seq: int, count: int) -> list[dict[str, Any]]:
    """The stored samples after ``seq``, once at least ``count`` of them are in."""
    found: list[dict[str, Any]] = []

    async def enough() -> bool:
        nonlocal found
        found = [s for s in await h.telemetry(boat) if s["seq"] > seq]
        return len(found) >= count

    await until_async(enough, f"{count} samples from the outage stored")
    return found


@pytest.mark.parametrize("action", ["keep_station", "stop", "return_home", "none"])
async def test_each_failsafe_action_after_a_cut_link(harbour: Harbour, action: str) -> None:
    h = harbour
    boat = await h.boat(
        f"fs-{action.replace('_', '-')}",
        current=DRIFT,
        failsafe={"action": action, "after_s": 0.5},
    )
    policy = await h.call("GET", f"/api/vehicles/{boat.vehicle_id}/failsafe")
    assert policy["failsafe"]["action"] == action and policy["failsafe"]["version"] == 1

    async def acked() -> bool:
        view = await h.call("GET", f"/api/vehicles/{boat.vehicle_id}")
        return view["failsafe_acked"] is True

    await until_async(acked, "the vehicle to acknowledge its policy")
    op = await h.operator(boat)
    command_id = await sail_east(h, boat, op)
    seq_at_cut = boat.agent.outbox.next_seq - 1
    engaged = await cut_and_mend(h, boat, sim_seconds=120.0)
    samples = await stored_after(h, boat, seq_at_cut, count=40)
    # Judge the last positions of the outage as the server stored them.
    tail = [boat.enu(s) for s in samples[-10:]]
    east, north = tail[-1]
    if action == "none":
        assert east > engaged[0] + 30, "with none the boat carries on east"
        assert (await h.command(command_id))["status"] in ("executing", "done")
    elif action == "return_home":
        assert east**2 + north**2 <= 3.0**2, f"home is (0, 0); the boat is at {tail[-1]}"
    elif action == "keep_station":
        assert all(((e - engaged[0]) ** 2 + (n - engaged[1]) ** 2) ** 0.5 <= 5 for e, n in tail)
    else:  # stop: thrust off, the current carries it north, it goes no further east
        assert north > engaged[1] + 3, "a stopped boat drifts with the current"
        assert east < engaged[0] + 10
    if action != "none":
        assert (await h.command(command_id))["status"] == "failed"

        async def recorded() -> bool:
            return bool(await h.events(boat, "failsafe_entered"))

        await until_async(recorded, "failsafe_entered recorded once the link is back")
        entered = await h.events(boat, "failsafe_entered")
        assert entered[0]["data"]["control_mode"] == "failsafe"
        # Dated when the boat took it, 120 s of its time (3 s here) before the link
        # was back and the server heard of it.
        waited = parse_ts(entered[0]["at"]) - parse_ts(entered[0]["data"]["since"])
        assert waited.total_seconds() >= 2.5, entered[0]


async def test_a_policy_changed_while_running_reaches_the_vehicle(harbour: Harbour) -> None:
    h = harbour
    boat = await h.boat("fs-change")
    assert boat.agent.helm.pilot.failsafe.version == 0  # the server's default until set
    r = await h.http.put(
        f"/api/vehicles/{boat.vehicle_id}/failsafe",
        headers=ADMIN,
        json={"action": "return_home", "after_s": 12, "home": boat.at(5, 5)},
    )
    assert r.status_code == 200, r.text
    await until(lambda: boat.agent.helm.pilot.failsafe.version == 1, "the new policy applied")
    assert boat.agent.helm.pilot.failsafe.action == "return_home"
    assert boat.agent.helm.link.after_s == 12

    async def acked() -> bool:
        view = await h.call("GET", f"/api/vehicles/{boat.vehicle_id}/failsafe")
        return view["acked"] is True and view["acked_version"] == 1

    await until_async(acked, "the acknowledgement recorded")


# ---- control that ends safely ---------------------------------------------------------------


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


async def holding(h: Harbour, boat: Boat) -> dict[str, Any]:
    """The system's keep_station, once the vehicle executes it."""
    found: dict[str, Any] = {}

    async def executing() -> bool:
        events = await h.events(boat, "hold_station")
        if not events or events[0]["data"]["command_id"] is None:
            return False
        found.update(await h.command(events[0]["data"]["command_id"]))
        return found["status"] == "executing"

    await until_async(executing, "the vehicle holding station")
    return found


async def test_a_revoked_lease_leaves_the_vehicle_holding_station(harbour: Harbour) -> None:
    h = harbour
    boat = await h.boat("hold-revoke", current=DRIFT)
    op = await h.operator(boat)
    go = await sail_east(h, boat, op)
    await h.call("POST", "/client/revoke_control", json={"instance_id": boat.instance_id})
    hold = await holding(h, boat)
    assert hold["type"] == "keep_station" and hold["issued_by"] == "system"
    replaced = await h.command(go)  # the vehicle ended it for the hold: superseded
    assert replaced["status"] == "cancelled", replaced
    assert replaced["history"][-1]["detail"].startswith("superseded_by keep_station c-")
    (event,) = await h.events(boat, "hold_station")
    assert event["data"]["reason"] == "revoked" and event["data"]["holder"].startswith("op-")
    await held_within(h, boat, metres=3.0, sim_seconds=60.0)


async def test_a_silent_operator_client_ends_the_lease_and_the_vehicle_holds(
    harbour: Harbour,
) -> None:
    h = harbour
    boat = await h.boat("hold-silent", current=DRIFT)
    op = await h.operator(boat, operator_timeout_s=2)

    async def heartbeats() -> None:  # the operator's client, alive
        while True:
            r = await h.http.post(
                "/client/heartbeat", headers=op, json={"instance_ids": [boat.instance_id]}
            )
            assert r.json()["held"] == [boat.instance_id]
            await asyncio.sleep(0.5)

    client = asyncio.create_task(heartbeats())
    try:
        await sail_east(h, boat, op)
        lease = (await h.call("GET", f"/api/vehicles/{boat.vehicle_id}"))["control"]
        assert lease["operator_timeout_s"] == 2
    finally:
        client.cancel()  # the client dies mid-mission
        with contextlib.suppress(asyncio.CancelledError):
            await client

    async def lapsed() -> bool:
        events = await h.events(boat, "control_expired")
        return any(e["data"].get("reason") == "operator_silent" for e in events)

    await until_async(lapsed, "the lease to lapse for the operator's silence")
    hold = await holding(h, boat)
    assert hold["type"] == "keep_station"
    await held_within(h, boat, metres=3.0, sim_seconds=40.0)
    r = await h.http.post(
        "/client/submit_control",
        headers=op,
        json={
            "instance_ids": [boat.instance_id],
            "command": {"type": "go_to", "args": boat.at(0, 0)},
        },
    )
    assert r.status_code == 409  # the lease is gone


# ---- plans that arrive whole -----------------------------------------------------------------


async def test_a_plan_received_in_part_never_runs(harbour: Harbour) -> None:
    h = harbour
    boat = await h.boat("plan-cut")
    op = await h.operator(boat)

    def drop_last_waypoint(path: str, body: dict[str, Any]) -> dict[str, Any]:
        for cmd in body.get("commands") or []:
            if path.endswith("/get_control") and cmd["type"] == "follow_path":
                cmd["args"]["waypoints"] = cmd["args"]["waypoints"][:-1]
        return body

    boat.link.rewrite = drop_last_waypoint
    waypoints = [boat.at(100, 0), boat.at(100, 100), boat.at(0, 100)]
    command_id = await h.submit(op, boat, "follow_path", {"waypoints": waypoints})

    async def ended() -> bool:
        return (await h.command(command_id))["status"] in ("rejected", "failed", "done")

    await until_async(ended, "the vehicle's answer")
    cmd = await h.command(command_id)
    assert cmd["status"] == "rejected"
    assert cmd["history"][-1]["detail"].startswith("plan_mismatch")
    assert cmd["args"]["path_hash"].startswith("sha256:")
    e, n = await h.position(boat)
    assert e**2 + n**2 <= 1.0, "the boat never set out"
    boat.link.rewrite = None
    whole = await h.submit(op, boat, "follow_path", {"waypoints": waypoints[:1]})

    async def accepted() -> bool:
        return (await h.command(whole))["status"] in ("executing", "done")

    await until_async(accepted, "a whole plan accepted")


async def test_a_vehicle_acknowledging_another_hash_fails_the_command(harbour: Harbour) -> None:
    h = harbour
    boat = await h.boat("plan-hash")
    op = await h.operator(boat)
    original = boat.agent.helm.pilot._ack

    def lying_ack(command_id: str, status: str, **extra: Any) -> Any:
        if extra.get("path_hash"):
            extra["path_hash"] = "sha256:" + "0" * 64
        return original(command_id, status, **extra)

    boat.agent.helm.pilot._ack = lying_ack  # type: ignore[method-assign]
    command_id = await h.submit(op, boat, "follow_path", {"waypoints": [boat.at(200, 0)]})

    async def failed() -> bool:
        return (await h.command(command_id))["status"] == "failed"

    await until_async(failed, "the command failed")
    cmd = await h.command(command_id)
    failed_entry = next(e for e in cmd["history"] if e["status"] == "failed")
    assert failed_entry["detail"].startswith("plan_mismatch")

    async def halted() -> bool:  # the abort reached the vehicle: it stopped the task
        return boat.agent.helm.pilot.active_id is None

    await until_async(halted, "the vehicle told to abort")


# ---- zones and the watch ---------------------------------------------------------------------


async def test_a_vehicle_pushed_into_a_zone_raises_a_breach_and_its_failsafe_holds_it(
    harbour: Harbour,
) -> None:
    h = harbour
    boat = await h.boat(
        "pushed",
        current=Current(east_mps=0.3, north_mps=0.0),
        failsafe={"action": "keep_station", "on_breach": True},
    )
    ring = [boat.at(x, y) for x, y in [(15, -20), (60, -20), (60, 20), (15, 20), (15, -20)]]
    zone = await h.call(
        "POST",
        "/api/zones",
        json={
            "name": "wreck",
            "kind": "no_go",
            "polygon": {"type": "Polygon", "coordinates": [[[p["lon"], p["lat"]] for p in ring]]},
        },
    )
    op = await h.operator(boat)
    r = await h.http.post(
        "/client/submit_control",
        headers=op,
        json={
            "instance_ids": [boat.instance_id],
            "command": {"type": "go_to", "args": boat.at(40, 0)},
        },
    )
    assert r.status_code == 422 and r.json()["error"]["code"] == "zone_violation"
    assert "wreck" in r.json()["error"]["message"]

    async def breached() -> bool:
        return bool(await h.events(boat, "zone_breach"))

    await until_async(breached, "the breach event")
    (event,) = await h.events(boat, "zone_breach")
    assert event["data"]["zone_id"] == zone["zone_id"] and event["data"]["zone"] == "wreck"
    assert event["data"]["action"] == "keep_station"
    held = await h.command(event["data"]["command_id"])
    assert held["type"] == "keep_station" and held["issued_by"] == "system"

    async def holding_now() -> bool:
        return (await h.command(held["command_id"]))["status"] == "executing"

    await until_async(holding_now, "the failsafe's keep_station executing")
    await held_within(h, boat, metres=3.0, sim_seconds=30.0)


# ---- collision forecast ----------------------------------------------------------------------


async def test_two_vehicles_on_crossing_courses_raise_collision_risk_before_they_meet(
    harbour: Harbour,
) -> None:
    h = harbour
    # a sails east through the crossing point, b north through it, from 60 m off each.
    a = await h.boat("cross-a", time_scale=5.0)
    b_start = a.at(60, -60)
    b = await h.boat("cross-b", start=(b_start["lat"], b_start["lon"]), time_scale=5.0)
    op = await h.operator(a, b)
    crossing = a.at(60, 0)
    await h.submit(op, a, "go_to", a.at(200, 0))
    await h.submit(op, b, "go_to", a.at(60, 200))

    async def risk() -> bool:
        return bool(await h.events(a, "collision_risk"))

    await until_async(risk, "collision_risk")
    (event,) = (await h.events(a, "collision_risk"))[:1]
    assert event["data"]["other_vehicle_id"] == "cross-b"
    assert (await h.events(b, "collision_risk"))[0]["data"]["other_vehicle_id"] == "cross-a"
    data = event["data"]
    assert data["distance_now_m"] > 10 and data["in_s"] > 0, "raised before they met"
    assert data["closest_m"] <= 10  # below the separation, rounded to 0.1 m (9.97 is 10.0)
    assert distance_m(data["lat"], data["lon"], crossing["lat"], crossing["lon"]) < 40
