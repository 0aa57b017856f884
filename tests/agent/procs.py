"""Real processes for end-to-end tests: a fleet-server and fleet-agents, on loopback.

Waiting is always a deadline loop on a condition (``wait_until``).
"""

from __future__ import annotations

import os
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import httpx

ROOT = Path(__file__).resolve().parents[2]
ADMIN_TOKEN = "admin-token-for-agent-e2e-tests-0123456789"
T = TypeVar("T")


def wait_until(
    probe: Callable[[], T | None], what: str, within_s: float = 30.0, every_s: float = 0.1
) -> T:
    """Call ``probe`` until it answers something truthy; that answer."""
    deadline = time.monotonic() + within_s
    last_error: Exception | None = None
    while time.monotonic() < deadline:
        try:
            answer = probe()
        except (httpx.HTTPError, sqlite3.Error) as exc:
            answer, last_error = None, exc
        if answer:
            return answer
        time.sleep(every_s)
    raise AssertionError(f"gave up after {within_s:.0f} s waiting for {what} ({last_error})")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(proc: subprocess.Popen | None, sig: int, grace_s: float = 15.0) -> None:
    if proc is None or proc.poll() is not None:
        return
    proc.send_signal(sig)
    try:
        proc.wait(timeout=grace_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=15)


class ServerProcess:
    def __init__(self, workdir: Path) -> None:
        self.workdir = workdir
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.proc: subprocess.Popen | None = None
        self.log = workdir / "server.log"
        self.env = {
            **os.environ,
            "FLEET_HOST": "127.0.0.1",
            "FLEET_PORT": str(self.port),
            "FLEET_ADMIN_TOKEN": ADMIN_TOKEN,
            "FLEET_SNAPSHOT_PATH": str(workdir / "store.snapshot"),
            "FLEET_SNAPSHOT_INTERVAL_S": "0.5",
            "FLEET_BUCKET_MAX_AGE_S": "0.5",
            "FLEET_LOG_LEVEL": "warning",
        }

    def start(self) -> None:
        with self.log.open("a") as log:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "server.cli"],
                cwd=self.workdir,
                env=self.env,
                stdout=log,
                stderr=subprocess.STDOUT,
            )
        # a minute: on a loaded machine (CI's two workers and their browsers) a start-up took 30 s
        wait_until(self._healthy, "the server to answer /healthz", within_s=60)

    def _healthy(self) -> bool:
        if self.proc is not None and self.proc.poll() is not None:
            raise AssertionError(f"the server exited: {self.log.read_text()[-2000:]}")
        return httpx.get(f"{self.url}/healthz", timeout=2).status_code == 200

    def kill(self) -> None:
        _stop(self.proc, signal.SIGKILL)

    def stop(self, grace_s: float = 30.0) -> None:
        """SIGTERM; a graceful stop waits for open long polls (up to their wait_s)."""
        _stop(self.proc, signal.SIGTERM, grace_s)


class AgentProcess:
    def __init__(
        self, server: ServerProcess, token: str, vehicle_id: str, outbox: Path, **options: Any
    ) -> None:
        self.args = [
            sys.executable, "-m", "vehicle_client.cli", "run",
            "--server", server.url, "--vehicle-id", vehicle_id, "--outbox", str(outbox),
        ]  # fmt: skip
        for key, value in options.items():
            self.args += [f"--{key.replace('_', '-')}", str(value)]
        self.env = {**os.environ, "FLEET_AGENT_TOKEN": token}
        self.outbox = outbox
        self.log = outbox.with_suffix(".log")
        self.proc: subprocess.Popen | None = None

    def start(self) -> None:
        with self.log.open("a") as log:
            self.proc = subprocess.Popen(
                self.args, cwd=ROOT, env=self.env, stdout=log, stderr=subprocess.STDOUT
            )

    def kill(self) -> None:
        _stop(self.proc, signal.SIGKILL)

    def stop(self) -> None:
        _stop(self.proc, signal.SIGTERM)

    def outbox_rows(self) -> int:
        """Samples waiting in the agent's outbox file (read-only peek)."""
        db = sqlite3.connect(f"file:{self.outbox}?mode=ro", uri=True)
        try:
            return db.execute("SELECT COUNT(*) FROM samples").fetchone()[0]
        finally:
            db.close()

    def next_seq(self) -> int:
        db = sqlite3.connect(f"file:{self.outbox}?mode=ro", uri=True)
        try:
            row = db.execute("SELECT value FROM meta WHERE key = 'next_seq'").fetchone()
            return int(row[0]) if row else 1
        finally:
            db.close()


class Fleet:
    """The HTTP calls an admin and an operator make, against a running server."""

    def __init__(self, server: ServerProcess) -> None:
        self.url = server.url

    def call(self, method: str, path: str, token: str = ADMIN_TOKEN, **kw: Any) -> Any:
        r = httpx.request(
            method, f"{self.url}{path}", headers={"Authorization": f"Bearer {token}"},
            timeout=10, **kw,
        )  # fmt: skip
        if r.status_code >= 400:
            raise AssertionError(f"{method} {path}: {r.status_code} {r.text}")
        return r.json()

    def has_route(self, method: str, path: str) -> bool:
        spec = httpx.get(f"{self.url}/openapi.json", timeout=10).json()
        return method.lower() in spec.get("paths", {}).get(path, {})

    def create_vehicle(self, vehicle_id: str) -> str:
        body = {"vehicle_id": vehicle_id, "name": vehicle_id, "vehicle_type": "usv"}
        return self.call("POST", "/api/vehicles", json=body)["token"]

    def create_operator(self, username: str, vehicles: list[str]) -> str:
        body = {"username": username, "role": "operator", "vehicles": vehicles}
        return self.call("POST", "/api/users", json=body)["token"]

    def online_instance(self, vehicle_id: str) -> str:
        def probe() -> str | None:
            v = self.call("GET", f"/api/vehicles/{vehicle_id}")
            return v["instance_id"] if v["presence"] == "online" and v["position"] else None

        return wait_until(probe, f"{vehicle_id} online with a position")

    def grant(self, instance_id: str, username: str) -> None:
        body = {"instance_id": instance_id, "user": username, "duration_s": 3600}
        self.call("POST", "/client/grant_control", json=body)

    def submit(self, token: str, instance_id: str, kind: str, args: dict, ttl_s: int = 600) -> str:
        body = {
            "instance_ids": [instance_id],
            "command": {"type": kind, "args": args},
            "ttl_s": ttl_s,
        }
        return self.call("POST", "/client/submit_control", token, json=body)["commands"][0][
            "command_id"
        ]

    def command(self, command_id: str) -> dict:
        return self.call("GET", f"/api/commands/{command_id}")

    def position(self, instance_id: str) -> dict:
        return self.call("GET", "/client/get_param", params={"instance_id": instance_id})[
            "position"
        ]

    def telemetry(self, vehicle_id: str) -> list[dict]:
        samples: list[dict] = []
        after = 0
        while True:
            page = self.call(
                "GET", f"/api/vehicles/{vehicle_id}/telemetry",
                params={"after_seq": after, "limit": 10000},
            )  # fmt: skip
            samples += page["samples"]
            if page["next_after_seq"] is None:
                return samples
            after = page["next_after_seq"]
