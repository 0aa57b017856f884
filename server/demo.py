"""``make demo``: the server on the embedded store with three simulated vehicles.

Starts the server, registers three vehicles near Biograd na Moru (43.94 N,
15.44 E) if they are not yet there, runs one fleet-agent process each, and
prints the dashboard URL and an admin token. Ctrl-C stops everything.

The demo keeps its world in ``data/`` (the store's snapshot and each vehicle's
outbox): started again, it finds its vehicles, and each simulated vehicle
starts where the server last saw it, not back at its first position.
``FLEET_SNAPSHOT_PATH`` moves the whole world: the outboxes go beside the snapshot.

Tokens, as ``fleet-server`` does: with no ``FLEET_ADMIN_TOKEN``, each start
makes a fresh admin token, prints it, and revokes the one printed at the
start before; with ``FLEET_ADMIN_TOKEN`` set, that one is the admin's and
nothing is printed. Each vehicle gets a fresh token at each start (its former
ones revoked), handed to its agent in the environment, never printed.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import signal
import subprocess
import sys
from pathlib import Path

import httpx
import uvicorn

from server.api.ws_direct import uvicorn_ws_options
from server.app import create_app
from server.cli import load_settings
from server.logs import log_config

#: The demo's world by default: the folder of the default ``snapshot_path``.
DATA = Path("data")
VEHICLES = [
    ("demo-usv-1", "H2OmniX Alpha", 43.9400, 15.4400),
    ("demo-usv-2", "H2OmniX Bravo", 43.9385, 15.4425),
    ("demo-usv-3", "H2OmniX Charlie", 43.9412, 15.4378),
]


async def _register(base: str, admin: str) -> dict[str, str]:
    """A fresh token per vehicle (created, or rotated when it exists already)."""
    tokens: dict[str, str] = {}
    headers = {"Authorization": f"Bearer {admin}"}
    async with httpx.AsyncClient(base_url=base, headers=headers, timeout=10) as client:
        for vehicle_id, name, _, _ in VEHICLES:
            r = await client.post(
                "/api/vehicles",
                json={"vehicle_id": vehicle_id, "name": name, "vehicle_type": "usv"},
            )
            if r.status_code == 409:
                r = await client.post(f"/api/vehicles/{vehicle_id}/rotate_token")
            r.raise_for_status()
            tokens[vehicle_id] = r.json()["token"]
    return tokens


async def _last_positions(base: str, admin: str) -> dict[str, tuple[float, float]]:
    """Where the server last saw each vehicle (a world kept from an earlier run)."""
    headers = {"Authorization": f"Bearer {admin}"}
    async with httpx.AsyncClient(base_url=base, headers=headers, timeout=10) as client:
        r = await client.get("/api/vehicles")
        r.raise_for_status()
    return {
        v["vehicle_id"]: (v["position"]["lat"], v["position"]["lon"])
        for v in r.json()["vehicles"]
        if v.get("position")
    }


def start_positions(last: dict[str, tuple[float, float]]) -> dict[str, tuple[float, float]]:
    """Each demo vehicle's start: where it was last seen, else its first position."""
    return {vid: last.get(vid, (lat, lon)) for vid, _, lat, lon in VEHICLES}


def world_folder(snapshot_path: Path) -> Path:
    """The folder of the demo's world (the snapshot's), made if it is not there. It holds
    the store, the tokens' digests and the outboxes: made the owner's alone, and so kept
    when it is the default ``data``; a folder of the user's own is left as they set it."""
    folder = snapshot_path.parent
    folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    if folder == DATA:
        folder.chmod(0o700)
    return folder


def _start_agents(
    base: str, tokens: dict[str, str], starts: dict[str, tuple[float, float]], world: Path
) -> list[subprocess.Popen[bytes]]:
    procs = []
    for vehicle_id, _, _, _ in VEHICLES:
        lat, lon = starts[vehicle_id]
        env = {
            **os.environ,
            "FLEET_AGENT_TOKEN": tokens[vehicle_id],  # not on the command line
            "FLEET_AGENT_PARENT_PID": str(os.getpid()),  # it stops when the demo is gone
        }
        procs.append(
            subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "vehicle_client.cli",
                    "run",
                    "--server",
                    base,
                    "--vehicle-id",
                    vehicle_id,
                    "--adapter",
                    "sim",
                    "--start",
                    f"{lat},{lon}",
                    "--rate-hz",
                    "1",
                    "--outbox",
                    str(world / f"{vehicle_id}.outbox"),
                ],
                env=env,
            )
        )
    return procs


async def main() -> None:
    settings = load_settings()
    world = world_folder(settings.snapshot_path)
    app = create_app(settings)
    server = uvicorn.Server(
        uvicorn.Config(
            app,
            host=settings.host,
            port=settings.port,
            log_level="warning",
            log_config=log_config("warning"),  # no token in any line (server/logs.py)
            **uvicorn_ws_options(),
        )
    )
    serving = asyncio.create_task(server.serve())
    while not server.started:
        if serving.done():
            return  # it failed to start (port taken?): uvicorn said why
        await asyncio.sleep(0.05)
    base = f"http://{settings.host}:{settings.port}"
    await _ready(base, serving)
    given = settings.admin_token
    # No FLEET_ADMIN_TOKEN: the one the server made at this start (and printed).
    admin = given.get_secret_value() if given else app.state.runtime.admin_token
    if admin is None:  # the store never became ready: the server said why
        server.should_exit = True
        await serving
        return
    starts = start_positions(await _last_positions(base, admin))
    agents = _start_agents(base, await _register(base, admin), starts, world)
    print(f"\nfleet-cloud demo is running (its world in {world}/)")
    print(f"  dashboard:   {base}/")
    print(f"  API docs:    {base}/docs")
    if given:
        print("  admin token: the one in FLEET_ADMIN_TOKEN")
    else:
        print(f"  admin token: {admin}   (new at each start; the one before is revoked)")
    print(f"  vehicles:    {', '.join(v[0] for v in VEHICLES)} (simulated, near Biograd na Moru)")
    print("Ctrl-C to stop.\n", flush=True)
    try:
        await serving
    finally:
        for proc in agents:
            proc.send_signal(signal.SIGINT)
        for proc in agents:
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=5)
            if proc.poll() is None:
                proc.kill()


async def _ready(base: str, serving: asyncio.Task[None], within_s: float = 60.0) -> None:
    """Until the server has loaded its store (``/readyz``): its admin token is made then."""
    async with httpx.AsyncClient(base_url=base, timeout=5) as client, asyncio.timeout(within_s):
        while not serving.done():
            with contextlib.suppress(httpx.HTTPError):
                if (await client.get("/readyz")).status_code == 200:
                    return
            await asyncio.sleep(0.1)


def _stop_as_on_ctrl_c(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _arguments(argv: list[str]) -> None:
    """The demo takes no options (its settings come from FLEET_* like the server's);
    ``--help`` says what it does instead of starting it."""
    parser = argparse.ArgumentParser(
        prog="python -m server.demo",
        description="Start fleet-server on the embedded store with three simulated "
        "vehicles (its world in ./data, or beside FLEET_SNAPSHOT_PATH), print the "
        "console's URL and an admin token; Ctrl-C stops everything. Settings: FLEET_* as "
        "for fleet-server (FLEET_PORT, FLEET_ADMIN_TOKEN, FLEET_SNAPSHOT_PATH, ...).",
    )
    parser.parse_args(argv)


if __name__ == "__main__":
    _arguments(sys.argv[1:])
    # uvicorn hands a SIGTERM back to the handler it found once it has shut down; the
    # default one would end the process before the simulated vehicles are stopped.
    signal.signal(signal.SIGTERM, _stop_as_on_ctrl_c)
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(main())
