"""Latency per hop with real processes: a fleet-server, one agent on the WebSocket and one
on HTTP, an operator's socket and a command carried out. Each hop's histogram on
``/metrics`` counts, and each vehicle's view carries its link delay (docs/live.md,
"Latency per hop"). Only counts are checked: the speed is ``make bench``'s.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import websockets
from prometheus_client.parser import text_string_to_metric_families

from tests.agent.procs import AgentProcess, Fleet, ServerProcess, wait_until
from tests.agent.test_e2e import START, commanded_vehicle, final_command, latlon

pytestmark = pytest.mark.slow

HISTOGRAMS = [
    ("fleet_hop_vehicle_to_server_seconds", {"transport": "ws"}),
    ("fleet_hop_vehicle_to_server_seconds", {"transport": "http"}),
    ("fleet_hop_server_to_operator_seconds", {}),
    ("fleet_command_submitted_to_delivered_seconds", {}),
    ("fleet_command_delivered_to_acked_seconds", {}),
    ("fleet_command_submitted_to_acked_seconds", {}),
]


@pytest.fixture
def server(tmp_path: Path) -> Iterator[ServerProcess]:
    proc = ServerProcess(tmp_path)
    proc.start()
    yield proc
    proc.stop(grace_s=2.0)


def counts(server: ServerProcess) -> dict[str, float]:
    """Each histogram's ``_count`` (with its labels), as ``/metrics`` says now."""
    text = httpx.get(f"{server.url}/metrics", timeout=5).text
    found: dict[str, float] = {}
    for family in text_string_to_metric_families(text):
        for s in family.samples:
            for name, labels in HISTOGRAMS:
                if s.name == f"{name}_count" and all(
                    s.labels.get(k) == v for k, v in labels.items()
                ):
                    found[f"{name}{labels or ''}"] = s.value
    return found


async def watch_telemetry(url: str, token: str, vehicle_id: str, events: int) -> None:
    """An operator's socket: subscribed to the vehicle's telemetry, until it has heard
    ``events`` changes (each one a server → operator hop)."""
    ws_url = url.replace("http", "ws", 1) + "/ws/client"
    topic = f"vehicle/{vehicle_id}/telemetry"
    headers = {"Authorization": f"Bearer {token}"}
    async with (
        asyncio.timeout(30),
        websockets.connect(ws_url, additional_headers=headers) as ws,
    ):
        await ws.send(json.dumps({"op": "subscribe", "id": "s", "topics": [topic]}))
        heard = 0
        while heard < events:
            frame = json.loads(await ws.recv())
            if frame.get("topic") == topic and not frame.get("snapshot"):
                heard += 1


def test_every_hop_is_measured_and_each_view_carries_its_link_delay(
    tmp_path: Path, server: ServerProcess
) -> None:
    fleet = Fleet(server)
    ws_agent, instance_id, operator = commanded_vehicle(
        tmp_path, server, fleet, "usv-hop-ws", transport="ws"
    )
    token = fleet.create_vehicle("usv-hop-http")
    http_agent = AgentProcess(
        server, token, "usv-hop-http", tmp_path / "usv-hop-http.db",
        start=f"{START[0]},{START[1]}", rate_hz=5, transport="http",
    )  # fmt: skip
    http_agent.start()
    try:
        fleet.online_instance("usv-hop-http")
        asyncio.run(watch_telemetry(server.url, operator, "usv-hop-ws", events=3))
        command = final_command(fleet, fleet.submit(operator, instance_id, "go_to", latlon(5, 5)))
        assert command["status"] == "done", command

        def all_counted() -> dict[str, float] | None:
            found = counts(server)
            return found if len(found) == len(HISTOGRAMS) and all(found.values()) else None

        wait_until(all_counted, "a count in every hop's histogram")

        def delays() -> dict[str, float] | None:
            views = fleet.call("GET", "/api/vehicles")["vehicles"]
            found = {v["vehicle_id"]: v.get("link_delay_ms") for v in views}
            return found if all(d is not None and d >= 0 for d in found.values()) else None

        assert set(wait_until(delays, "a link delay in each vehicle's view")) == {
            "usv-hop-ws",
            "usv-hop-http",
        }
    finally:
        ws_agent.stop()
        http_agent.stop()
