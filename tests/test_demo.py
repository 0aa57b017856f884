"""``make demo`` as a newcomer runs it: a server, three simulated vehicles online, a clean stop.

The demo runs as its own process (``python -m server.demo``) in a scratch
folder, on a free port; stopping it with SIGTERM (what a process manager or
``timeout`` sends) must stop its simulated vehicles too, not leave them
running against a server that is gone.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import httpx
import psutil

from tests.agent.procs import free_port, wait_until


def test_demo_serves_three_simulated_vehicles_and_stops_them_on_sigterm(tmp_path: Path) -> None:
    port = free_port()
    env = {
        **os.environ,
        "FLEET_HOST": "127.0.0.1",
        "FLEET_PORT": str(port),
        "FLEET_SNAPSHOT_PATH": str(tmp_path / "demo.snapshot"),
    }
    env.pop("FLEET_MONGO_URL", None)
    env.pop("FLEET_REDIS_URL", None)
    env.pop("FLEET_ADMIN_TOKEN", None)
    log = tmp_path / "demo.log"
    with log.open("wb") as out:
        demo = subprocess.Popen(
            [sys.executable, "-m", "server.demo"], cwd=tmp_path, env=env, stdout=out, stderr=out
        )
    agents: list[psutil.Process] = []
    try:

        def admin_token() -> str | None:
            found = re.search(r"admin token: (\S+)", log.read_text(errors="replace"))
            return found.group(1) if found else None

        token = wait_until(admin_token, "the demo's banner with the admin token", within_s=60)
        assert f"http://127.0.0.1:{port}/" in log.read_text()
        headers = {"Authorization": f"Bearer {token}"}

        def all_online() -> list[str] | None:
            r = httpx.get(f"http://127.0.0.1:{port}/api/vehicles", headers=headers, timeout=5)
            r.raise_for_status()
            vehicles = r.json()["vehicles"]
            online = sorted(v["vehicle_id"] for v in vehicles if v["presence"] == "online")
            return online if len(online) == 3 else None

        online = wait_until(all_online, "three simulated vehicles online", within_s=60)
        assert online == ["demo-usv-1", "demo-usv-2", "demo-usv-3"]
        agents = psutil.Process(demo.pid).children(recursive=True)
        assert len(agents) == 3

        demo.send_signal(signal.SIGTERM)
        demo.wait(timeout=30)
        _, alive = psutil.wait_procs(agents, timeout=15)
        assert alive == [], f"simulated vehicles left running: {[p.pid for p in alive]}"
    finally:  # whatever failed above, nothing of the demo outlives the test
        if demo.poll() is None:
            agents = agents or psutil.Process(demo.pid).children(recursive=True)
            demo.kill()
        for agent in agents:
            if agent.is_running():
                agent.kill()
