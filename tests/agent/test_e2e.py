"""fleet-agent against a real fleet-server process, both on loopback.

The agent runs as ``python -m vehicle_client.cli run`` with its simulator
sped up by ``--time-scale``; commands go in through the operator's HTTP API
and results are read back through it. Every wait is a deadline on a
condition.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.agent.procs import AgentProcess, Fleet, ServerProcess, wait_until
from vehicle_client.geo import LocalFrame, distance_m

pytestmark = pytest.mark.slow

START = (43.94, 15.44)
FRAME = LocalFrame(*START)
FINAL = {"done", "failed", "rejected", "expired", "cancelled"}
TELEMETRY = "/api/vehicles/{vehicle_id}/telemetry"


@pytest.fixture
def server(tmp_path: Path) -> Iterator[ServerProcess]:
    proc = ServerProcess(tmp_path)
    proc.start()
    yield proc
    proc.stop(grace_s=2.0)  # then killed: the test is over, nothing more to keep


@pytest.fixture
def fleet(server: ServerProcess) -> Fleet:
    return Fleet(server)


def latlon(east: float, north: float) -> dict[str, float]:
    lat, lon = FRAME.to_latlon(east, north)
    return {"lat": lat, "lon": lon}


def commanded_vehicle(
    tmp_path: Path, server: ServerProcess, fleet: Fleet, vehicle_id: str, **options: object
) -> tuple[AgentProcess, str, str]:
    """A vehicle with a running agent and an operator holding its lease."""
    token = fleet.create_vehicle(vehicle_id)
    operator = fleet.create_operator(f"op-{vehicle_id}", [vehicle_id])
    agent = AgentProcess(
        server, token, vehicle_id, tmp_path / f"{vehicle_id}.db",
        start=f"{START[0]},{START[1]}", **{"rate_hz": 5, "time_scale": 20, **options},
    )  # fmt: skip
    agent.start()
    instance_id = fleet.online_instance(vehicle_id)
    fleet.grant(instance_id, f"op-{vehicle_id}")
    return agent, instance_id, operator


def final_command(fleet: Fleet, command_id: str, within_s: float = 90.0) -> dict:
    def probe() -> dict | None:
        command = fleet.command(command_id)
        return command if command["status"] in FINAL else None

    return wait_until(probe, f"command {command_id} to end", within_s)


def require_telemetry_route(fleet: Fleet) -> None:
    if not fleet.has_route("get", TELEMETRY):
        pytest.skip(f"the server has no GET {TELEMETRY} yet (needed to read seqs back)")


def assert_every_seq_once(samples: list[dict], through: int) -> None:
    seqs = [s["seq"] for s in samples]
    assert len(seqs) == len(set(seqs)), "a seq was stored twice"
    missing = sorted(set(range(1, through + 1)) - set(seqs))
    assert not missing, f"{len(missing)} seqs never stored, first {missing[:10]}"


def test_go_to_reaches_the_waypoint_and_reports_done(
    tmp_path: Path, server: ServerProcess, fleet: Fleet
) -> None:
    agent, instance_id, operator = commanded_vehicle(tmp_path, server, fleet, "usv-goto")
    try:
        target = latlon(30.0, 20.0)
        command_id = fleet.submit(operator, instance_id, "go_to", target)
        command = final_command(fleet, command_id)
        assert command["status"] == "done", command
        assert [h["status"] for h in command["history"]][-3:] == ["accepted", "executing", "done"]

        def arrived() -> bool:
            p = fleet.position(instance_id)
            return distance_m(p["lat"], p["lon"], target["lat"], target["lon"]) <= 1.5

        wait_until(arrived, "the reported position at the waypoint")
    finally:
        agent.stop()


def test_keep_station_holds_against_the_current(
    tmp_path: Path, server: ServerProcess, fleet: Fleet
) -> None:
    agent, instance_id, operator = commanded_vehicle(
        tmp_path, server, fleet, "usv-hold", current="0.25,90"
    )
    try:
        center = latlon(0.0, 0.0)
        args = {**center, "radius_m": 3.0}
        command_id = fleet.submit(operator, instance_id, "keep_station", args)

        def off(p: dict) -> float:
            return distance_m(p["lat"], p["lon"], center["lat"], center["lon"])

        wait_until(lambda: off(fleet.position(instance_id)) <= 3.0, "back on station")
        seen: dict[int, float] = {}

        def held_long_enough() -> bool:
            p = fleet.position(instance_id)
            seen[p["seq"]] = off(p)
            return len(seen) >= 40  # 8 s at 5 Hz: over two minutes of simulated time

        wait_until(held_long_enough, "40 positions while holding", within_s=60)
        assert max(seen.values()) <= 3.0, sorted(seen.values())[-5:]
        assert fleet.command(command_id)["status"] == "executing"
    finally:
        agent.stop()


def test_follow_path_completes_with_progress(
    tmp_path: Path, server: ServerProcess, fleet: Fleet
) -> None:
    agent, instance_id, operator = commanded_vehicle(
        tmp_path, server, fleet, "usv-path", current="0.1,0"
    )
    try:
        legs = [(25.0, 0.0), (25.0, 25.0), (0.0, 25.0)]
        args = {"waypoints": [latlon(*p) for p in legs]}
        command_id = fleet.submit(operator, instance_id, "follow_path", args)
        wait_until(
            lambda: (fleet.command(command_id).get("progress") or 0) > 0, "progress reported"
        )
        command = final_command(fleet, command_id, within_s=120)
        assert command["status"] == "done", command
        assert command["progress"] in (1.0, 100.0)
        end = latlon(*legs[-1])
        p = fleet.position(instance_id)
        assert distance_m(p["lat"], p["lon"], end["lat"], end["lon"]) <= 2.0
    finally:
        agent.stop()


def test_a_server_down_for_ten_seconds_loses_and_repeats_no_sample(
    tmp_path: Path, server: ServerProcess, fleet: Fleet
) -> None:
    require_telemetry_route(fleet)
    token = fleet.create_vehicle("usv-outage")
    agent = AgentProcess(server, token, "usv-outage", tmp_path / "outage.db", rate_hz=5)
    agent.start()
    try:
        wait_until(lambda: len(fleet.telemetry("usv-outage")) >= 10, "first samples stored")
        server.kill()  # no clean shutdown: what was not durable is gone from the server
        killed_at = agent.next_seq()
        wait_until(lambda: agent.next_seq() >= killed_at + 50, "10 s of samples (5 Hz) while down")
        server.start()
        target = agent.next_seq() - 1
        wait_until(
            lambda: max(s["seq"] for s in fleet.telemetry("usv-outage")) >= target,
            "the outage's samples delivered",
            within_s=60,
        )
    finally:
        agent.stop()
    assert_every_seq_once(fleet.telemetry("usv-outage"), target)


def test_a_killed_agent_resumes_its_outbox(
    tmp_path: Path, server: ServerProcess, fleet: Fleet
) -> None:
    require_telemetry_route(fleet)
    token = fleet.create_vehicle("usv-restart")
    outbox = tmp_path / "restart.db"
    first = AgentProcess(server, token, "usv-restart", outbox, rate_hz=5)
    first.start()
    try:
        wait_until(lambda: len(fleet.telemetry("usv-restart")) >= 10, "first samples stored")
        server.stop()
        stopped_at = first.next_seq()
        wait_until(lambda: first.outbox_rows() >= 25, "a backlog in the outbox")
        wait_until(lambda: first.next_seq() >= stopped_at + 25, "samples taken while down")
    finally:
        first.kill()
    backlog_through = first.next_seq() - 1
    server.start()
    second = AgentProcess(server, token, "usv-restart", outbox, rate_hz=5)
    second.start()
    try:
        wait_until(
            lambda: max(s["seq"] for s in fleet.telemetry("usv-restart")) > backlog_through + 5,
            "the old backlog and new samples delivered",
            within_s=60,
        )
    finally:
        second.stop()
    samples = fleet.telemetry("usv-restart")
    assert_every_seq_once(samples, max(s["seq"] for s in samples))


def test_a_gateway_runs_several_vehicles_over_one_link(
    tmp_path: Path, server: ServerProcess, fleet: Fleet
) -> None:
    for vid in ("gw-a", "gw-b"):
        fleet.create_vehicle(vid)
    gateway = fleet.call(
        "POST", "/api/gateways", json={"gateway_id": "gw", "vehicles": ["gw-a", "gw-b"]}
    )
    config = tmp_path / "gateway.toml"
    config.write_text(
        f'server = "{server.url}"\nrate_hz = 2\noutbox_dir = "{tmp_path / "gw"}"\n'
        '[[vehicles]]\nvehicle_id = "gw-a"\nstart = "43.94,15.44"\n'
        '[[vehicles]]\nvehicle_id = "gw-b"\nstart = "43.941,15.441"\n'
    )
    agent = AgentProcess(server, gateway["token"], "unused", tmp_path / "gw.db")
    agent.args = [*agent.args[:3], "gateway", "--config", str(config)]
    agent.start()
    try:
        a, b = fleet.online_instance("gw-a"), fleet.online_instance("gw-b")
        assert a != b
        pb = fleet.position(b)
        assert math.isclose(pb["lat"], 43.941, abs_tol=1e-4)
    finally:
        agent.stop()
