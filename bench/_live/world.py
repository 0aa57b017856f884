"""The bench's world on the server: vehicles, users and a gateway; vehicles connected."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import websockets
from websockets.asyncio.client import ClientConnection

from bench._live.clients import RawHttp, ws_call, ws_connect
from bench._live.config import ADMIN
from bench._live.server import ServerHandle


@dataclass
class World:
    server: ServerHandle
    vehicles: list[tuple[str, str]] = field(default_factory=list)  # (vehicle_id, token)
    tokens: dict[str, str] = field(default_factory=dict)
    gateway_vehicle: str = "bench-gw-unit"
    setup_s: float = 0.0


async def create_vehicles(world: World, total: int, parallel: int = 32) -> float:
    """Register vehicles (admin, concurrently) until the world has ``total``; seconds taken."""
    started = time.perf_counter()
    ids = [f"bv-{i:05d}" for i in range(len(world.vehicles), total)]
    results: dict[str, str] = {}
    queue = iter(ids)

    async def worker() -> None:
        http = await RawHttp(world.server.port, ADMIN).open()
        try:
            for vid in queue:
                body = {"vehicle_id": vid, "name": vid, "vehicle_type": "usv"}
                status, answer = await http.request("POST", "/api/vehicles", body)
                if status != 201:
                    raise RuntimeError(f"creating {vid}: {status} {answer}")
                results[vid] = answer["token"]
        finally:
            await http.close()

    async with asyncio.timeout(900):
        await asyncio.gather(*(worker() for _ in range(parallel)))
    world.vehicles.extend((vid, results[vid]) for vid in ids)
    return time.perf_counter() - started


async def build_world(server: ServerHandle, n_vehicles: int) -> World:
    world = World(server)
    started = time.perf_counter()
    await create_vehicles(world, n_vehicles)
    ids = [vid for vid, _ in world.vehicles]
    admin = await RawHttp(server.port, ADMIN).open()
    try:
        gv = world.gateway_vehicle
        status, answer = await admin.request(
            "POST", "/api/vehicles", {"vehicle_id": gv, "name": gv, "vehicle_type": "usv"}
        )
        assert status == 201, answer
        status, answer = await admin.request(
            "POST", "/api/gateways", {"gateway_id": "bench-gw", "vehicles": [gv]}
        )
        assert status == 201, answer
        world.tokens["gateway"] = answer["token"]
        users = {
            "pub": ("bench-pub", "viewer", []),
            "sub": ("bench-sub", "viewer", []),
            "op": ("bench-op", "operator", [ids[0], gv] if ids else [gv]),
        }
        for key, (name, role, vehicles) in users.items():
            status, answer = await admin.request(
                "POST", "/api/users", {"username": name, "role": role, "vehicles": vehicles}
            )
            assert status == 201, answer
            world.tokens[key] = answer["token"]
    finally:
        await admin.close()
    world.setup_s = time.perf_counter() - started
    return world


CAPS = ["stop", "go_to", "keep_station", "follow_path"]


@dataclass
class VehicleSocket:
    vehicle_id: str
    ws: ClientConnection
    instance_id: str
    seq: int


async def connect_vehicles(
    world: World, pairs: Sequence[tuple[str, str]], parallel: int = 64
) -> tuple[list[VehicleSocket], int]:
    """Connect and ``start_instance`` each vehicle; (sockets in order, failures)."""
    out: dict[int, VehicleSocket] = {}
    failures = 0
    queue = iter(enumerate(pairs))

    async def worker() -> None:
        nonlocal failures
        for index, (vid, token) in queue:
            try:
                ws = await ws_connect(f"{world.server.ws}/ws/vehicle", token)
                ack = await ws_call(
                    ws, "start_instance", "s", vehicle_id=vid, name=vid,
                    vehicle_type="usv", capabilities=CAPS,
                )  # fmt: skip
                if not ack.get("ok"):
                    raise RuntimeError(f"start_instance {vid}: {ack}")
                out[index] = VehicleSocket(vid, ws, ack["instance_id"], int(ack["last_seq"]))
            except (OSError, TimeoutError, websockets.WebSocketException, RuntimeError):
                failures += 1

    async with asyncio.timeout(600):
        await asyncio.gather(*(worker() for _ in range(parallel)))
    return [out[i] for i in sorted(out)], failures
