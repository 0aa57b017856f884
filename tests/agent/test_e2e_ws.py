"""fleet-agent over the WebSocket (/ws/vehicle) against a real fleet-server process.

Which link the agent uses is read from the server's ``fleet_ws_connections``
gauge (``/metrics``) and the agent's own log ("started over ws"). Every wait
is a deadline on a condition.
"""

from __future__ import annotations

import asyncio
import itertools
import json
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest
import websockets

from tests.agent.procs import AgentProcess, Fleet, ServerProcess, free_port, wait_until
from tests.agent.refusing_proxy import RefusingProxy
from tests.agent.test_e2e import (
    START,
    assert_every_seq_once,
    commanded_vehicle,
    final_command,
    latlon,
    require_telemetry_route,
)
from vehicle_client.geo import distance_m

pytestmark = pytest.mark.slow


@pytest.fixture
def server(tmp_path: Path) -> Iterator[ServerProcess]:
    proc = ServerProcess(tmp_path)
    proc.start()
    yield proc
    proc.stop(grace_s=2.0)


@pytest.fixture
def fleet(server: ServerProcess) -> Fleet:
    return Fleet(server)


def ws_connections(server: ServerProcess) -> float:
    for line in httpx.get(f"{server.url}/metrics", timeout=5).text.splitlines():
        if line.startswith("fleet_ws_connections"):
            return float(line.split()[-1])
    raise AssertionError("the server's /metrics has no fleet_ws_connections")


def logged(agent: AgentProcess, text: str) -> bool:
    return text in agent.log.read_text()


def test_go_to_over_the_websocket_reaches_the_waypoint(
    tmp_path: Path, server: ServerProcess, fleet: Fleet
) -> None:
    agent, instance_id, operator = commanded_vehicle(
        tmp_path, server, fleet, "usv-ws", transport="ws"
    )
    try:
        assert ws_connections(server) == 1
        wait_until(lambda: logged(agent, "started over ws"), "the agent's log: over ws")
        target = latlon(30.0, 20.0)
        command = final_command(fleet, fleet.submit(operator, instance_id, "go_to", target))
        assert command["status"] == "done", command
        assert [h["status"] for h in command["history"]][-3:] == ["accepted", "executing", "done"]

        def arrived() -> bool:
            p = fleet.position(instance_id)
            return distance_m(p["lat"], p["lon"], target["lat"], target["lon"]) <= 1.5

        wait_until(arrived, "the reported position at the waypoint")
        assert not logged(agent, "HTTP long-poll")
    finally:
        agent.stop()


def test_a_server_down_for_ten_seconds_over_the_websocket_loses_no_sample(
    tmp_path: Path, server: ServerProcess, fleet: Fleet
) -> None:
    require_telemetry_route(fleet)
    token = fleet.create_vehicle("usv-ws-outage")
    agent = AgentProcess(
        server, token, "usv-ws-outage", tmp_path / "outage.db", rate_hz=5, transport="ws"
    )
    agent.start()
    try:
        wait_until(lambda: len(fleet.telemetry("usv-ws-outage")) >= 10, "first samples stored")
        assert ws_connections(server) == 1
        server.kill()  # no clean shutdown: what was not durable is gone from the server
        killed_at = agent.next_seq()
        wait_until(lambda: agent.next_seq() >= killed_at + 50, "10 s of samples (5 Hz) while down")
        server.start()
        target = agent.next_seq() - 1
        wait_until(
            lambda: max(s["seq"] for s in fleet.telemetry("usv-ws-outage")) >= target,
            "the outage's samples delivered",
            within_s=60,
        )
        assert ws_connections(server) == 1  # back on the WebSocket, not on HTTP
    finally:
        agent.stop()
    assert_every_seq_once(fleet.telemetry("usv-ws-outage"), target)


def test_a_gateway_over_one_websocket_runs_its_vehicles(
    tmp_path: Path, server: ServerProcess, fleet: Fleet
) -> None:
    vehicles = ["gws-a", "gws-b", "gws-c"]
    for vid in vehicles:
        fleet.create_vehicle(vid)
    token = fleet.call("POST", "/api/gateways", json={"gateway_id": "gws", "vehicles": vehicles})[
        "token"
    ]
    operator = fleet.create_operator("op-gws", vehicles)
    config = tmp_path / "gateway.toml"
    config.write_text(
        f'server = "{server.url}"\nrate_hz = 5\ntime_scale = 20\ntransport = "ws"\n'
        f'outbox_dir = "{tmp_path / "gw"}"\n'
        + "".join(
            f'[[vehicles]]\nvehicle_id = "{vid}"\nstart = "{START[0]},{START[1] + i * 1e-3}"\n'
            for i, vid in enumerate(vehicles)
        )
    )
    agent = AgentProcess(server, token, "unused", tmp_path / "gw.db")
    agent.args = [*agent.args[:3], "gateway", "--config", str(config)]
    agent.start()
    try:
        instances = [fleet.online_instance(vid) for vid in vehicles]
        assert len(set(instances)) == 3
        assert ws_connections(server) == 1  # one upstream link for the three
        fleet.grant(instances[1], "op-gws")
        p = fleet.position(instances[1])
        target = {"lat": p["lat"] + 1e-4, "lon": p["lon"]}
        command = final_command(fleet, fleet.submit(operator, instances[1], "go_to", target))
        assert command["status"] == "done", command
        for vid in vehicles:
            assert len(fleet.telemetry(vid)) >= 5, vid
    finally:
        agent.stop()


def test_falls_back_to_http_when_the_upgrade_is_refused_and_returns_to_the_websocket(
    tmp_path: Path, server: ServerProcess, fleet: Fleet
) -> None:
    with RefusingProxy(server.port).running() as proxy:
        token = fleet.create_vehicle("usv-fallback")
        agent = AgentProcess(
            server, token, "usv-fallback", tmp_path / "fallback.db",
            rate_hz=5, time_scale=20, retry_ws_s=3,
        )  # fmt: skip
        agent.args[agent.args.index("--server") + 1] = proxy.url
        agent.start()
        try:
            instance_id = fleet.online_instance("usv-fallback")
            assert proxy.refused >= 1
            wait_until(lambda: logged(agent, "falling back to HTTP long-poll"), "the fallback log")
            assert ws_connections(server) == 0
            operator = fleet.create_operator("op-fb2", ["usv-fallback"])
            fleet.grant(instance_id, "op-fb2")
            target = latlon(10.0, 5.0)
            command = final_command(fleet, fleet.submit(operator, instance_id, "go_to", target))
            assert command["status"] == "done", command  # the long poll carried it
            tried = proxy.refused
            wait_until(lambda: proxy.refused >= tried + 2, "the WebSocket tried again twice")
            events = fleet.call(
                "GET", "/api/events", params={"vehicle_id": "usv-fallback", "kind": "instance"}
            )["events"]
            # Tried from within the session on HTTP: no new start, no "resumed" each time.
            assert [e["data"]["action"] for e in events] == ["started"], events

            proxy.refuse_upgrades = False  # the proxy lets WebSockets through now
            wait_until(lambda: ws_connections(server) == 1, "the agent back on the WebSocket")
            wait_until(lambda: logged(agent, "leaving HTTP long-poll"), "the return log")
            back = fleet.submit(operator, instance_id, "go_to", latlon(0.0, 0.0))
            assert final_command(fleet, back)["status"] == "done"
        finally:
            agent.stop()


async def _recv(
    ws: websockets.ClientConnection, want: Callable[[dict], bool], within_s: float = 20
) -> dict:
    """The first frame ``want`` accepts, within a deadline."""
    async with asyncio.timeout(within_s):
        while True:
            frame = json.loads(await ws.recv())
            if want(frame):
                return frame


async def _published_until_heard(
    unit: websockets.ClientConnection, op: websockets.ClientConnection, topic: str
) -> dict:
    """Publish ``{m: 3}``, ``{m: 4}``... on ``topic`` until ``op`` hears one; that event."""
    async with asyncio.timeout(30):
        for m in itertools.count(3):
            await unit.send(json.dumps({"op": "publish", "topic": topic, "data": {"m": m}}))
            try:
                return await _recv(op, _event_on(topic), within_s=0.5)
            except TimeoutError:
                continue
    raise AssertionError("unreachable")


def _event_on(topic: str) -> Callable[[dict], bool]:
    return lambda f: f["op"] == "event" and f["topic"] == topic and not f.get("snapshot")


def test_gateway_forwards_its_units_topics_on_demand(
    tmp_path: Path, server: ServerProcess, fleet: Fleet
) -> None:
    vehicles = ["gwu-a", "gwu-b", "gwu-sim"]
    for vid in vehicles:
        fleet.create_vehicle(vid)
    token = fleet.call("POST", "/api/gateways", json={"gateway_id": "gwu", "vehicles": vehicles})[
        "token"
    ]
    viewer = fleet.create_operator("op-gwu", vehicles)
    port = free_port()
    config = tmp_path / "gateway.toml"
    config.write_text(
        f'server = "{server.url}"\nlisten = "127.0.0.1:{port}"\n'
        f'outbox_dir = "{tmp_path / "gw"}"\n[[vehicles]]\nvehicle_id = "gwu-sim"\n'
    )
    agent = AgentProcess(server, token, "unused", tmp_path / "gw.db")
    agent.args = [*agent.args[:3], "gateway", "--config", str(config)]
    agent.start()
    sonar, plan = "vehicle/gwu-a/sonar_depth", "user/op-gwu/plan/gwu-b"  # a plan for gwu-b

    async def scenario() -> None:
        unit = f"ws://127.0.0.1:{port}/?vehicle_id="
        async with (
            websockets.connect(unit + "gwu-a", compression=None) as a,
            websockets.connect(unit + "gwu-b", compression=None) as b,
        ):
            await a.send(json.dumps({"op": "register", "id": "r", "topics": [sonar]}))
            assert (await _recv(a, lambda f: f["op"] == "ack"))["ok"] is True
            await b.send(json.dumps({"op": "subscribe", "id": "s", "topics": [sonar, plan]}))
            assert (await _recv(b, lambda f: f["op"] == "ack"))["ok"] is True
            # Only a local unit consumes it: delivered by the gateway itself.
            await a.send(json.dumps({"op": "publish", "topic": sonar, "data": {"m": 1}}))
            assert (await _recv(b, _event_on(sonar)))["data"] == {"m": 1}

            op_url = server.url.replace("http", "ws", 1) + "/ws/client"
            headers = {"Authorization": f"Bearer {viewer}"}
            async with websockets.connect(op_url, additional_headers=headers) as op:
                await op.send(json.dumps({"op": "subscribe", "id": "o", "topics": [sonar]}))
                await _recv(op, lambda f: f["op"] == "ack")
                # The unit hears of its new consumer upstream (its routes, relayed).
                await _recv(
                    a, lambda f: f["op"] == "routes" and "user:op-gwu" in f["produces"][sonar]
                )
                # Asked above, but a unit below consumes it: it stays below (API.md).
                await a.send(json.dumps({"op": "publish", "topic": sonar, "data": {"m": 2}}))
                assert (await _recv(b, _event_on(sonar)))["data"] == {"m": 2}
                # Downward: what the unit subscribed to, from above.
                await op.send(json.dumps({"op": "publish", "topic": plan, "data": [1, 2]}))
                assert (await _recv(b, _event_on(plan)))["data"] == [1, 2]
                # No unit below consumes it any more: up it goes, once the gateway hears.
                await b.send(json.dumps({"op": "unsubscribe", "id": "u", "topics": [sonar]}))
                assert (await _recv(b, lambda f: f["op"] == "ack"))["ok"] is True
                first = await _published_until_heard(a, op, sonar)
                assert first["data"]["m"] >= 3, first  # m 2 never went up
            # Outside its namespace: refused by the gateway, even kept local.
            await b.send(json.dumps({"op": "publish", "id": "p", "topic": sonar, "data": 0}))
            refused = await _recv(b, lambda f: f["op"] == "ack" and f["id"] == "p")
            assert refused["ok"] is False and refused["error"]["code"] == "forbidden"

    try:
        fleet.online_instance("gwu-sim")
        wait_until(lambda: logged(agent, "local units: ws://"), "the gateway's unit server")
        asyncio.run(scenario())
    finally:
        agent.stop()


def test_a_refused_token_ends_the_agent_with_one_clear_message(
    server: ServerProcess, tmp_path: Path
) -> None:
    """Exit 2 with the refusal said once: no asyncio 'Future exception was never retrieved'
    (the close failed an op's waiter while its own send failed too), in runs 5 of 6 before."""
    for run in range(3):
        agent = AgentProcess(server, "fct_not-a-token", "usv-x", tmp_path / f"o{run}.db")
        agent.start()
        assert agent.proc is not None
        assert agent.proc.wait(timeout=60) == 2
        log = agent.log.read_text()
        assert "refused the token" in log and "FLEET_AGENT_TOKEN" in log
        assert "never retrieved" not in log, log
