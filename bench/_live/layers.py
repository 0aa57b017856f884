"""Section 4, three layers: unit -> gateway -> cloud -> operator, against bridged Mosquitto."""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import websockets
from websockets.asyncio.client import ClientConnection
from websockets.asyncio.server import ServerConnection

from bench._live.clients import (
    close_all,
    next_event,
    run_async,
    time_hops,
    ws_call,
    ws_connect,
)
from bench._live.config import Config
from bench._live.world import World
from bench._mosquitto import MqttPump, mosquitto
from bench._stats import fmt3, lat_stats
from bench.pubsub_mqtt import SIZES


async def fleet_three_layer(world: World, size: int, count: int, warmup: int) -> list[int]:
    """unit -> in-bench gateway relay -> /ws/vehicle (gateway token) -> cloud -> /ws/client."""
    server = world.server
    vid = world.gateway_vehicle
    topic = f"vehicle/{vid}/x"
    upstream = await ws_connect(f"{server.ws}/ws/vehicle", world.tokens["gateway"])
    operator = await ws_connect(f"{server.ws}/ws/client", world.tokens["op"])
    ack = await ws_call(operator, "subscribe", "s", topics=[topic])
    assert ack["ok"], ack

    async def drain_upstream() -> None:  # acks, routes pushes: read and dropped
        with contextlib.suppress(websockets.ConnectionClosed):
            async for _ in upstream:
                pass

    async def relay(conn: ServerConnection) -> None:
        """The gateway: each unit frame goes up as a publish on the unit's behalf."""
        async for frame in conn:
            msg = json.loads(frame)
            if msg.get("op") == "publish":
                msg["vehicle_id"] = vid
                await upstream.send(json.dumps(msg, separators=(",", ":")))

    drain = asyncio.create_task(drain_upstream())
    gateway = await websockets.serve(relay, "127.0.0.1", 0, compression=None, ping_interval=None)
    unit: ClientConnection | None = None
    try:
        port = next(iter(gateway.sockets)).getsockname()[1]
        unit = await ws_connect(f"ws://127.0.0.1:{port}")
        frame = json.dumps({"op": "publish", "topic": topic, "data": "x" * size})
        return await time_hops(unit.send, lambda: next_event(operator), frame, count, warmup)
    finally:
        await close_all([ws for ws in (unit, operator, upstream) if ws is not None])
        gateway.close()
        await gateway.wait_closed()
        drain.cancel()


def mqtt_chain_hop(pub_port: int, sub_port: int, size: int, count: int, warmup: int) -> list[int]:
    """One message in flight, published on one broker, received from another (bridged)."""
    pump = MqttPump()
    try:
        sub = pump.connect(sub_port, "bench-chain-sub")
        pub = pump.connect(pub_port, "bench-chain-pub")
        topic = "bench/chain/x"
        arrivals: list[int] = []
        sub.on_message = lambda *args: arrivals.append(time.perf_counter_ns())
        pump.subscribe(sub, topic)
        # The bridge connects on its own time: probe until a message crosses it.
        deadline = time.monotonic() + 20
        while not arrivals:
            if time.monotonic() > deadline:
                raise RuntimeError("the mosquitto bridge did not carry a message within 20 s")
            pub.publish(topic, b"probe", qos=0)
            with contextlib.suppress(RuntimeError):
                pump.until(lambda: bool(arrivals), "", within_s=0.2)
        for _ in range(10):  # late probes, read and forgotten
            pump.once(0.02)
        arrivals.clear()
        payload = bytes(size)
        samples: list[int] = []
        for _ in range(warmup + count):
            before = len(arrivals)
            t0 = time.perf_counter_ns()
            pub.publish(topic, payload, qos=0)
            pump.until(
                lambda before=before: len(arrivals) > before,  # type: ignore[misc]
                "a message did not cross the bridge",
            )
            samples.append(arrivals[-1] - t0)
        return samples[warmup:]
    finally:
        pump.close()


BRIDGE = """
connection bench-bridge
address 127.0.0.1:{port}
topic bench/# out 0
cleansession true
try_private false
notifications false
bridge_attempt_unsubscribe false
start_type automatic
restart_timeout 1
keepalive_interval 60
"""


def section_layers(
    cfg: Config, world: World, workdir: Path, core: int | None, report: Callable[[str], None]
) -> dict[str, Any]:
    size = SIZES[0]
    fleet_runs: list[dict[str, float]] = []
    mqtt_runs: list[dict[str, float]] = []
    with (
        mosquitto(workdir, core, name="cloud") as cloud,
        mosquitto(workdir, core, BRIDGE.format(port=cloud), name="edge") as edge,
    ):
        for _ in range(cfg.runs):
            fleet_runs.append(
                lat_stats(run_async(fleet_three_layer(world, size, cfg.count, cfg.warmup)))
            )
            mqtt_runs.append(lat_stats(mqtt_chain_hop(edge, cloud, size, cfg.count, cfg.warmup)))
    report(
        f"  three layers {size} B: fleet median {fmt3([r['median_ms'] for r in fleet_runs])}"
        f" p99 {fmt3([r['p99_ms'] for r in fleet_runs])};"
        f" mosquitto bridge median {fmt3([r['median_ms'] for r in mqtt_runs])}"
        f" p99 {fmt3([r['p99_ms'] for r in mqtt_runs])} ms"
    )
    return {"size": size, "fleet": fleet_runs, "mosquitto_bridge": mqtt_runs}
