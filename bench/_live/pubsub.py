"""Section 1, pub-sub: one-hop latency and 1 -> 1 throughput, /ws/client against Mosquitto."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench._live.clients import (
    close_all,
    next_event,
    run_async,
    time_hops,
    ws_call,
    ws_connect,
)
from bench._live.config import WINDOW, Config
from bench._live.world import World
from bench._mosquitto import MqttPump, mosquitto
from bench._relay import bare_relay
from bench._stats import fmt3
from bench._wsync import HandWs, time_hops_sync
from bench.pubsub_mqtt import SIZES, LatencyResult, mqtt_one_hop


def fleet_one_hop(world: World, size: int, count: int, warmup: int) -> LatencyResult:
    """Publisher to subscriber through ``/ws/client``, clients driven by hand (``bench._wsync``)."""
    ws = world.server.ws
    sub = HandWs(f"{ws}/ws/client", world.tokens["sub"])
    pub = HandWs(f"{ws}/ws/client", world.tokens["pub"])
    try:
        topic = "user/bench-pub/x"
        ack = sub.call("subscribe", "s", topics=[topic])
        assert ack["ok"], ack
        frame = json.dumps({"op": "publish", "topic": topic, "data": "x" * size})
        samples = time_hops_sync(pub.send, sub.next_event, frame, count, warmup)
        return LatencyResult.from_samples("fleet-ws", size, samples)
    finally:
        pub.close()
        sub.close()


async def fleet_one_hop_asyncio(world: World, size: int, count: int, warmup: int) -> LatencyResult:
    """The same hop with asyncio ``websockets`` clients: what an asyncio program sees."""
    ws = world.server.ws
    sub = await ws_connect(f"{ws}/ws/client", world.tokens["sub"])
    pub = await ws_connect(f"{ws}/ws/client", world.tokens["pub"])
    try:
        topic = "user/bench-pub/x"
        ack = await ws_call(sub, "subscribe", "s", topics=[topic])
        assert ack["ok"], ack
        frame = json.dumps({"op": "publish", "topic": topic, "data": "x" * size})
        samples = await time_hops(pub.send, lambda: next_event(sub), frame, count, warmup)
        return LatencyResult.from_samples("fleet-ws-asyncio", size, samples)
    finally:
        await close_all([pub, sub])


def relay_one_hop(port: int, size: int, count: int, warmup: int) -> LatencyResult:
    """The same hop through the bare relay (``bench._relay``): the stack's floor."""
    sub = HandWs(f"ws://127.0.0.1:{port}/sub")
    pub = HandWs(f"ws://127.0.0.1:{port}/pub")
    try:
        frame = json.dumps({"op": "publish", "topic": "user/bench-pub/x", "data": "x" * size})
        deadline = time.monotonic() + 60
        while True:  # the relay takes the subscriber once it is open: retry until it has
            pub.send(frame)
            sub.sock.settimeout(0.2)
            try:
                sub.recv()
                break
            except TimeoutError:
                if time.monotonic() > deadline:
                    raise
            finally:
                sub.sock.settimeout(60)
        samples = time_hops_sync(pub.send, sub.recv, frame, count, warmup)
        return LatencyResult.from_samples("bare-relay", size, samples)
    finally:
        pub.close()
        sub.close()


async def fleet_throughput(world: World, size: int, count: int) -> dict[str, float]:
    ws = world.server.ws
    sub = await ws_connect(f"{ws}/ws/client", world.tokens["sub"])
    pub = await ws_connect(f"{ws}/ws/client", world.tokens["pub"])
    try:
        topic = "user/bench-pub/t"
        ack = await ws_call(sub, "subscribe", "s", topics=[topic])
        assert ack["ok"], ack
        frame = json.dumps({"op": "publish", "topic": topic, "data": "x" * size})
        state = {"sent": 0, "received": 0, "dropped": 0}
        room = asyncio.Event()

        async def reader() -> None:
            async for got in sub:
                if not isinstance(got, str):
                    continue
                if got.startswith('{"op":"event"'):
                    state["received"] += 1
                elif got.startswith('{"op":"lagging"'):
                    state["dropped"] += int(json.loads(got)["dropped"])
                if state["sent"] - state["received"] - state["dropped"] <= WINDOW // 2:
                    room.set()
                if state["received"] + state["dropped"] >= count:
                    return

        task = asyncio.create_task(reader())
        started = time.perf_counter()
        async with asyncio.timeout(300):
            while state["sent"] < count:
                if state["sent"] - state["received"] - state["dropped"] >= WINDOW:
                    room.clear()
                    await room.wait()
                    continue
                await pub.send(frame)
                state["sent"] += 1
            await task
        elapsed = time.perf_counter() - started
        return {
            "msgs_per_s": state["received"] / elapsed,
            "received": state["received"],
            "dropped": state["dropped"],
        }
    finally:
        await close_all([pub, sub])


def mqtt_throughput(port: int, size: int, count: int) -> dict[str, float]:
    pump = MqttPump()
    try:
        sub = pump.connect(port, "bench-tp-sub")
        pub = pump.connect(port, "bench-tp-pub")
        topic = "bench/tp"
        received = [0]
        sub.on_message = lambda *args: received.__setitem__(0, received[0] + 1)
        pump.subscribe(sub, topic)
        payload = bytes(size)
        sent = 0
        started = time.perf_counter()
        deadline = time.monotonic() + 300
        while received[0] < count:
            if time.monotonic() > deadline:
                raise RuntimeError("mosquitto throughput: timed out")
            while sent < count and sent - received[0] < WINDOW:
                pub.publish(topic, payload, qos=0)
                sent += 1
            pump.once(0.05)
        elapsed = time.perf_counter() - started
        return {"msgs_per_s": received[0] / elapsed, "received": received[0], "dropped": 0}
    finally:
        pump.close()


def _hops(
    cfg: Config, world: World, mqtt_port: int, relay_port: int, size: int
) -> dict[str, Callable[[], LatencyResult]]:
    """The one-hop measurements of one size, by row name."""
    count, warmup = cfg.count, cfg.warmup
    return {
        "fleet": lambda: fleet_one_hop(world, size, count, warmup),
        "mosquitto": lambda: mqtt_one_hop(mqtt_port, size, count, warmup),
        "relay": lambda: relay_one_hop(relay_port, size, count, warmup),
        "fleet_asyncio": lambda: run_async(fleet_one_hop_asyncio(world, size, count, warmup)),
    }


def section_pubsub(
    cfg: Config, world: World, workdir: Path, core: int | None, report: Callable[[str], None]
) -> dict[str, Any]:
    result: dict[str, Any] = {"latency": {}, "throughput": {}}
    with mosquitto(workdir, core, name="hop") as port, bare_relay(workdir, core) as relay:
        for size in SIZES:
            runs: dict[str, list[dict[str, float]]] = {
                "fleet": [], "mosquitto": [], "relay": [], "fleet_asyncio": []
            }  # fmt: skip
            hops = _hops(cfg, world, port, relay, size)
            for _ in range(cfg.runs):  # interleaved, so all see the same machine
                for name, hop in hops.items():
                    got = hop()
                    runs[name].append({"median_ms": got.median_ms, "p99_ms": got.p99_ms})
            result["latency"][size] = runs
            report(
                f"  pub-sub {size:>6} B: "
                + "; ".join(
                    f"{name} median {fmt3([r['median_ms'] for r in rs])}"
                    f" p99 {fmt3([r['p99_ms'] for r in rs])}"
                    for name, rs in runs.items()
                )
                + " ms"
            )
        size = SIZES[0]
        fleet_tp = []
        mqtt_tp = []
        for _ in range(cfg.runs):
            fleet_tp.append(run_async(fleet_throughput(world, size, cfg.tp_count)))
            mqtt_tp.append(mqtt_throughput(port, size, cfg.tp_count))
        result["throughput"] = {"size": size, "fleet": fleet_tp, "mosquitto": mqtt_tp}
        report(
            f"  throughput {size} B: fleet {fmt3([r['msgs_per_s'] for r in fleet_tp], 0)} msg/s,"
            f" mosquitto {fmt3([r['msgs_per_s'] for r in mqtt_tp], 0)} msg/s"
        )
    return result
