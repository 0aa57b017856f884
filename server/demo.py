"""``make demo``: the server on the embedded store with three simulated vehicles.

Starts the server, registers three vehicles near Biograd na Moru (43.94 N,
15.44 E) if they are not yet there, runs one fleet-agent process each, and
prints the dashboard URL and an admin token. Ctrl-C stops everything.
"""

from __future__ import annotations

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
from server.logs import log_config
from server.services.auth import new_token
from server.settings import Settings

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


def _start_agents(base: str, tokens: dict[str, str]) -> list[subprocess.Popen[bytes]]:
    procs = []
    for vehicle_id, _, lat, lon in VEHICLES:
        env = {**os.environ, "FLEET_AGENT_TOKEN": tokens[vehicle_id]}  # not on the command line
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
                    str(DATA / f"{vehicle_id}.outbox"),
                ],
                env=env,
            )
        )
    return procs


async def main() -> None:
    settings = Settings()
    admin = settings.admin_token.get_secret_value() if settings.admin_token else new_token()
    settings = settings.model_copy(update={"admin_token": Settings(admin_token=admin).admin_token})
    server = uvicorn.Server(
        uvicorn.Config(
            create_app(settings),
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
    agents = _start_agents(base, await _register(base, admin))
    print(f"\nfleet-cloud demo is running (embedded store in {settings.snapshot_path})")
    print(f"  dashboard:   {base}/")
    print(f"  API docs:    {base}/docs")
    print(f"  admin token: {admin}")
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


def _stop_as_on_ctrl_c(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


if __name__ == "__main__":
    DATA.mkdir(exist_ok=True)
    # uvicorn hands a SIGTERM back to the handler it found once it has shut down; the
    # default one would end the process before the simulated vehicles are stopped.
    signal.signal(signal.SIGTERM, _stop_as_on_ctrl_c)
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(main())
