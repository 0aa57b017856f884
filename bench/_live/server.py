"""The fleet-server under test: ``python -m server.cli`` as a pinned subprocess."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

import httpx

from bench._live.config import ROOT, SERVER_CMD, SERVER_ENV
from bench._proc import child_setup, free_port, stop, wait_for_port


@dataclass
class ServerHandle:
    base: str
    port: int
    pid: int

    @property
    def ws(self) -> str:
        return self.base.replace("http://", "ws://")


@contextlib.contextmanager
def fleet_server(
    workdir: Path, core: int | None, extra_env: Mapping[str, str] | None = None
) -> Iterator[ServerHandle]:
    """``python -m server.cli`` on a free loopback port (its output in ``workdir``);
    ``extra_env`` over the bench's settings."""
    port = free_port()
    env = {
        **os.environ,
        **SERVER_ENV,
        **(extra_env or {}),
        "FLEET_PORT": str(port),
        "FLEET_SNAPSHOT_PATH": str(workdir / "fleet-store.snapshot"),
    }
    env.pop("FLEET_MONGO_URL", None)
    env.pop("FLEET_REDIS_URL", None)
    log = (workdir / "server.log").open("wb")
    process = subprocess.Popen(
        SERVER_CMD,
        cwd=ROOT,
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
        preexec_fn=child_setup(core),
    )
    try:
        wait_for_port(port, process, "fleet-server", 60)
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(f"{base}/readyz", timeout=2).status_code == 200:
                    break
            time.sleep(0.1)
        else:
            raise RuntimeError("fleet-server did not become ready")
        yield ServerHandle(base, port, process.pid)
    finally:
        stop(process, signal.SIGINT)
        log.close()
