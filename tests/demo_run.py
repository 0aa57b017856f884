"""``python -m server.demo`` as a process in a scratch folder, for the tests that run it."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import httpx
import psutil

from tests.agent.procs import wait_until


def start_demo(folder: Path, port: int, log: Path) -> subprocess.Popen[bytes]:
    """The demo on ``port``, its world in ``folder/data``, its output in ``log``."""
    env = {
        **os.environ,
        "FLEET_HOST": "127.0.0.1",
        "FLEET_PORT": str(port),
        "FLEET_SNAPSHOT_PATH": str(folder / "data" / "fleet-store.snapshot"),
    }
    for name in ("FLEET_MONGO_URL", "FLEET_REDIS_URL", "FLEET_ADMIN_TOKEN"):
        env.pop(name, None)
    with log.open("wb") as out:
        return subprocess.Popen(
            [sys.executable, "-m", "server.demo"], cwd=folder, env=env, stdout=out, stderr=out
        )


def admin_token(log: Path, within_s: float = 60) -> str:
    """The admin token the demo's banner shows."""

    def printed() -> str | None:
        found = re.search(r"admin token: (\S+)", log.read_text(errors="replace"))
        return found.group(1) if found else None

    return wait_until(printed, f"the demo's banner with the admin token in {log}", within_s)


def vehicles(base: str, token: str) -> dict[str, dict[str, Any]]:
    r = httpx.get(f"{base}/api/vehicles", headers={"Authorization": f"Bearer {token}"}, timeout=5)
    r.raise_for_status()
    return {v["vehicle_id"]: v for v in r.json()["vehicles"]}


def wait_online(base: str, token: str, ids: list[str], within_s: float = 60) -> None:
    """Until each of ``ids`` is online with a position."""

    def all_there() -> bool:
        fleet = vehicles(base, token)
        return all(
            fleet.get(i, {}).get("presence") == "online" and fleet[i].get("position") for i in ids
        )

    wait_until(all_there, f"{', '.join(ids)} online with a position", within_s)


def stop_demo(demo: subprocess.Popen[bytes]) -> None:
    """SIGTERM, as a process manager would; its agents go with it (killed if they stay)."""
    agents = psutil.Process(demo.pid).children(recursive=True) if demo.poll() is None else []
    demo.send_signal(signal.SIGTERM)
    try:
        demo.wait(timeout=30)
    finally:
        if demo.poll() is None:
            demo.kill()
        _, alive = psutil.wait_procs(agents, timeout=15)
        for agent in alive:
            agent.kill()
