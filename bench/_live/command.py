"""Section 2, commands: ``POST /client/submit_control`` until the push reaches the vehicle."""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from collections.abc import Callable, Sequence
from typing import Any

import websockets
from websockets.asyncio.client import ClientConnection

from bench._live.clients import RawHttp, close_all
from bench._live.config import ADMIN
from bench._live.world import VehicleSocket, World, connect_vehicles
from bench._stats import fmt3, lat_stats


class PushReader:
    """Reads one vehicle socket: stamps ``command`` pushes, resolves acks by id."""

    def __init__(self, ws: ClientConnection) -> None:
        self.ws = ws
        self.command: asyncio.Future[tuple[int, dict[str, Any]]] | None = None
        self.acks: dict[str, asyncio.Future[dict[str, Any]]] = {}
        self.task = asyncio.create_task(self._run())

    async def _run(self) -> None:
        with contextlib.suppress(websockets.ConnectionClosed):
            async for frame in self.ws:
                now = time.perf_counter_ns()
                if not isinstance(frame, str):
                    continue
                msg = json.loads(frame)
                if msg.get("op") == "command":
                    if self.command is not None and not self.command.done():
                        self.command.set_result((now, msg))
                elif msg.get("op") == "ack":
                    fut = self.acks.pop(msg.get("id", ""), None)
                    if fut is not None and not fut.done():
                        fut.set_result(msg)

    async def call(self, op: str, op_id: str, **fields: Any) -> dict[str, Any]:
        fut: asyncio.Future[dict[str, Any]] = asyncio.get_running_loop().create_future()
        self.acks[op_id] = fut
        await self.ws.send(json.dumps({"op": op, "id": op_id, **fields}))
        return await asyncio.wait_for(fut, 30)


async def command_latency(
    world: World,
    levels: Sequence[int],
    runs: int,
    count: int,
    warmup: int,
    report: Callable[[str], None],
) -> list[dict[str, Any]]:
    server = world.server
    admin = await RawHttp(server.port, ADMIN).open()
    operator = await RawHttp(server.port, world.tokens["op"]).open()
    sockets: list[VehicleSocket] = []
    results: list[dict[str, Any]] = []
    reader: PushReader | None = None
    try:
        for level in levels:
            if len(sockets) < level:
                more, failures = await connect_vehicles(world, world.vehicles[len(sockets) : level])
                if failures:
                    raise RuntimeError(f"command bench: {failures} vehicles failed to connect")
                sockets.extend(more)
            measured = sockets[0]
            if reader is None:
                reader = PushReader(measured.ws)
                status, answer = await admin.request(
                    "POST",
                    "/client/grant_control",
                    {"instance_id": measured.instance_id, "user": "bench-op", "duration_s": 3600},
                )
                if status != 200:
                    raise RuntimeError(f"grant_control: {status} {answer}")
            body = {
                "instance_ids": [measured.instance_id],
                "command": {"type": "go_to", "args": {"lat": 43.95, "lon": 15.45}},
                "ttl_s": 60,
            }
            per_run: list[dict[str, float]] = []
            for run in range(runs):
                samples: list[int] = []
                async with asyncio.timeout(300):
                    for i in range(warmup + count):
                        fut: asyncio.Future[tuple[int, dict[str, Any]]]
                        fut = asyncio.get_running_loop().create_future()
                        reader.command = fut
                        t0 = time.perf_counter_ns()
                        status, answer = await operator.request(
                            "POST", "/client/submit_control", body
                        )
                        if status != 202:
                            raise RuntimeError(f"submit_control: {status} {answer}")
                        arrived, push = await fut
                        samples.append(arrived - t0)
                        ack = await reader.call(
                            "update_fbmessage",
                            f"a{level}-{run}-{i}",
                            instance_id=measured.instance_id,
                            control_mode="remote",
                            acks=[
                                {"command_id": push["command_id"], "status": "accepted"},
                                {"command_id": push["command_id"], "status": "done"},
                            ],
                        )
                        if not ack.get("ok"):
                            raise RuntimeError(f"update_fbmessage: {ack}")
                per_run.append(lat_stats(samples[warmup:]))
            results.append({"vehicles": level, "runs": per_run})
            report(
                f"  command @ {level:>5} vehicles: median {fmt3([r['median_ms'] for r in per_run])}"
                f" ms, p99 {fmt3([r['p99_ms'] for r in per_run])} ms"
            )
    finally:
        if reader is not None:
            reader.task.cancel()
        await close_all([s.ws for s in sockets])
        await admin.close()
        await operator.close()
    return results
