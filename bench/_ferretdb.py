"""FerretDB for the benches: the binary ``make bench`` builds (``FLEET_FERRETDB_BIN``),
started on a free loopback port with a fresh SQLite folder."""

from __future__ import annotations

import contextlib
import os
import subprocess
from collections.abc import Iterator
from pathlib import Path

from bench._proc import free_port, stop, wait_for_port

ROOT = Path(__file__).resolve().parent.parent


def ferretdb_binary() -> Path:
    given = os.environ.get("FLEET_FERRETDB_BIN")
    if given:
        return Path(given)
    found = sorted((ROOT / ".cache" / "ferretdb").glob("*/bin/ferretdb"))
    if not found:
        raise RuntimeError(
            "no FerretDB binary: run `make bench` (it builds it) or set FLEET_FERRETDB_BIN"
        )
    return found[-1]


@contextlib.contextmanager
def ferretdb(workdir: Path) -> Iterator[str]:
    """A FerretDB on a free loopback port keeping its data in ``workdir``; its URL."""
    port = free_port()
    data = workdir / "ferretdb"
    data.mkdir(parents=True, exist_ok=True)
    process = subprocess.Popen(
        [
            str(ferretdb_binary()),
            "--handler=sqlite",
            f"--sqlite-url=file:{data}/",
            f"--listen-addr=127.0.0.1:{port}",
            f"--state-dir={data}",
            "--debug-addr=-",
            "--telemetry=disable",
            "--log-level=error",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        wait_for_port(port, process, "FerretDB", 30)
        yield f"mongodb://127.0.0.1:{port}/?directConnection=true"
    finally:
        stop(process)
