"""``make demo`` as a newcomer runs it: a server, three simulated vehicles online, a clean stop;
run again, the same world.

The demo runs as its own process (``python -m server.demo``) in a scratch
folder, on a free port; stopping it with SIGTERM (what a process manager or
``timeout`` sends) must stop its simulated vehicles too, not leave them
running against a server that is gone.
"""

from __future__ import annotations

import math
import os
import re
import signal
import stat
import subprocess
import sys
from pathlib import Path
from typing import Any

import httpx
import psutil

from tests.agent.procs import free_port, wait_until
from tests.demo_run import admin_token, start_demo, stop_demo, vehicles, wait_online


def test_demo_serves_three_simulated_vehicles_and_stops_them_on_sigterm(tmp_path: Path) -> None:
    port = free_port()
    env = {
        **os.environ,
        "FLEET_HOST": "127.0.0.1",
        "FLEET_PORT": str(port),
        "FLEET_SNAPSHOT_PATH": str(tmp_path / "world" / "demo.snapshot"),
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
        # The agents' outboxes (readings, commands seen) beside the snapshot: the whole
        # world moved by FLEET_SNAPSHOT_PATH, nothing left in ./data.
        data = tmp_path / "world"
        assert stat.S_IMODE(data.stat().st_mode) == 0o700
        assert not (tmp_path / "data").exists()
        outboxes = list(data.glob("*.outbox"))
        assert outboxes and all(stat.S_IMODE(p.stat().st_mode) == 0o600 for p in outboxes)

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


def _metres(a: tuple[float, float], b: tuple[float, float]) -> float:
    north = (a[0] - b[0]) * 111_320.0
    east = (a[1] - b[1]) * 111_320.0 * math.cos(math.radians(a[0]))
    return math.hypot(north, east)


def test_a_restarted_demo_resumes_its_vehicles_where_they_were_with_a_new_admin_token(
    tmp_path: Path,
) -> None:
    """Run twice in one folder: a vehicle moved in the first run starts the second where
    the first left it; the first run's admin token no longer works (README, make demo)."""
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    first_start = (43.9400, 15.4400)  # demo-usv-1's first position (server/demo.py)

    demo = start_demo(tmp_path, port, tmp_path / "first.log")
    try:
        first = admin_token(tmp_path / "first.log")
        headers = {"Authorization": f"Bearer {first}"}
        wait_online(base, first, ["demo-usv-1"])
        iid = vehicles(base, first)["demo-usv-1"]["instance_id"]
        body = {"instance_id": iid, "user": "admin", "duration_s": 600}
        assert httpx.post(f"{base}/client/grant_control", headers=headers, json=body).is_success
        order = {"instance_ids": [iid], "command": {"type": "go_to",
                 "args": {"lat": 43.9410, "lon": 15.4400}}, "ttl_s": 60}  # fmt: skip
        assert httpx.post(f"{base}/client/submit_control", headers=headers, json=order).is_success

        def moved() -> tuple[float, float] | None:
            pos = vehicles(base, first)["demo-usv-1"]["position"]
            here = (pos["lat"], pos["lon"])
            return here if _metres(here, first_start) > 5 else None

        wait_until(moved, "demo-usv-1 five metres on its way north", 90)
    finally:
        stop_demo(demo)

    demo = start_demo(tmp_path, port, tmp_path / "second.log")
    try:
        second = admin_token(tmp_path / "second.log")
        assert second != first
        old = httpx.get(f"{base}/api/vehicles", headers={"Authorization": f"Bearer {first}"})
        assert old.status_code == 401  # the token printed before is revoked
        stored = vehicles(base, second)["demo-usv-1"]
        last_seen = (stored["position"]["lat"], stored["position"]["lon"])
        assert _metres(last_seen, first_start) > 5
        seq_before = stored["position"]["seq"]

        def sample_of_the_second_run() -> dict[str, Any] | None:
            v = vehicles(base, second)["demo-usv-1"]
            return v if v["presence"] == "online" and v["position"]["seq"] > seq_before else None

        resumed = wait_until(sample_of_the_second_run, "a sample of the second run", 60)
        here = (resumed["position"]["lat"], resumed["position"]["lon"])
        assert _metres(here, last_seen) < 2.0, (here, last_seen)  # where it was left
        assert _metres(here, first_start) > 4.0  # not back at its first position
    finally:
        stop_demo(demo)


def test_a_demo_killed_takes_its_vehicles_with_it_and_starts_again(tmp_path: Path) -> None:
    """``kill -9`` of the demo (a field test) left its simulated vehicles running, each
    holding its outbox: the next demo's vehicles could not start ("outbox in use"). They
    stop when the demo is gone, and the demo started again has all three online."""
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    ids = ["demo-usv-1", "demo-usv-2", "demo-usv-3"]
    demo = start_demo(tmp_path, port, tmp_path / "first.log")
    try:
        wait_online(base, admin_token(tmp_path / "first.log"), ids)
        agents = psutil.Process(demo.pid).children(recursive=True)
        assert len(agents) == 3
    finally:
        demo.kill()
        demo.wait(timeout=30)
    _, alive = psutil.wait_procs(agents, timeout=20)
    for agent in alive:
        agent.kill()
    assert alive == [], f"simulated vehicles left running: {[p.pid for p in alive]}"
    demo = start_demo(tmp_path, port, tmp_path / "second.log")
    try:
        wait_online(base, admin_token(tmp_path / "second.log"), ids)
        assert "in use" not in (tmp_path / "second.log").read_text(errors="replace")
    finally:
        stop_demo(demo)


def test_demo_help_says_what_it_does_and_starts_nothing(tmp_path: Path) -> None:
    ran = subprocess.run(
        [sys.executable, "-m", "server.demo", "--help"],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert ran.returncode == 0 and "usage: python -m server.demo" in ran.stdout, ran
    assert not (tmp_path / "data").exists()  # no store, no vehicles: nothing started
