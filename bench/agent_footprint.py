"""fleet-agent footprint at 5 Hz, and its outbox drain rate after a 10-minute outage.

Runs a real fleet-server and a real fleet-agent (simulator adapter) on
loopback, as processes:

1. footprint: the agent at 5 Hz for ``--measure-s`` seconds after a warm-up,
   once over HTTP long-poll and once over the WebSocket (``--transport``);
   its resident memory (RSS) and CPU share of one core (psutil). Goals
   from issue 4: at most 60 MB RSS, at most 3 % of one core.
2. drain: an outbox holding 10 minutes of 5 Hz samples (3,000) taken while
   the link was down; the agent starts and the bench times how long until
   the outbox is empty (everything durable on the server): samples per
   second.

    python -m bench.agent_footprint [--measure-s 30] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import sqlite3
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

import httpx
import psutil

ROOT = Path(__file__).resolve().parents[1]
ADMIN = "bench-admin-token-0123456789abcdef"
GOALS = {"rss_mb": 60.0, "cpu_pct": 3.0}


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _until(probe, what: str, within_s: float = 60.0, every_s: float = 0.1):
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        try:
            answer = probe()
        except (httpx.HTTPError, sqlite3.Error):
            answer = None
        if answer:
            return answer
        time.sleep(every_s)
    raise SystemExit(f"bench: gave up waiting for {what}")


def _server(workdir: Path) -> tuple[subprocess.Popen, str]:
    port = _port()
    env = {
        **os.environ,
        "FLEET_PORT": str(port),
        "FLEET_ADMIN_TOKEN": ADMIN,
        "FLEET_SNAPSHOT_PATH": str(workdir / "store.snapshot"),
        "FLEET_SNAPSHOT_INTERVAL_S": "1",
        "FLEET_LOG_LEVEL": "warning",
    }
    log = (workdir / "server.log").open("w")
    proc = subprocess.Popen(
        [sys.executable, "-m", "server.cli"],
        cwd=workdir,
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    url = f"http://127.0.0.1:{port}"
    _until(lambda: httpx.get(f"{url}/healthz", timeout=2).status_code == 200, "the server")
    return proc, url


def _vehicle(url: str, vehicle_id: str) -> str:
    r = httpx.post(
        f"{url}/api/vehicles",
        headers={"Authorization": f"Bearer {ADMIN}"},
        json={"vehicle_id": vehicle_id, "name": vehicle_id},
        timeout=10,
    )
    r.raise_for_status()
    return r.json()["token"]


def _agent(
    url: str, token: str, vehicle_id: str, outbox: Path, transport: str = "http"
) -> subprocess.Popen:
    args = [
        sys.executable,
        "-m",
        "vehicle_client.cli",
        "run",
        "--server",
        url,
        "--vehicle-id",
        vehicle_id,
        "--outbox",
        str(outbox),
        "--rate-hz",
        "5",
        "--log-level",
        "WARNING",
        "--transport",
        transport,
    ]
    log = outbox.with_suffix(".log").open("w")
    return subprocess.Popen(
        args,
        cwd=ROOT,
        env={**os.environ, "FLEET_AGENT_TOKEN": token},
        stdout=log,
        stderr=subprocess.STDOUT,
    )


def _rows(outbox: Path) -> int:
    db = sqlite3.connect(f"file:{outbox}?mode=ro", uri=True)
    try:
        return db.execute("SELECT COUNT(*) FROM samples").fetchone()[0]
    finally:
        db.close()


def _stop(proc: subprocess.Popen) -> None:
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=5)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def footprint(
    url: str, workdir: Path, warmup_s: float, measure_s: float, transport: str = "http"
) -> dict:
    vehicle_id = f"bench-foot-{transport}"
    outbox = workdir / f"{vehicle_id}.db"
    agent = _agent(url, _vehicle(url, vehicle_id), vehicle_id, outbox, transport)
    try:
        _until(lambda: _rows(outbox) >= 0 and agent.poll() is None, "the agent")
        time.sleep(warmup_s)  # a benchmark's measuring window, not a test wait
        p = psutil.Process(agent.pid)
        cpu0, t0 = p.cpu_times(), time.monotonic()
        peak = 0
        while time.monotonic() - t0 < measure_s:
            peak = max(peak, p.memory_info().rss)
            time.sleep(0.5)
        cpu1, t1 = p.cpu_times(), time.monotonic()
        used = (cpu1.user + cpu1.system) - (cpu0.user + cpu0.system)
        return {
            "transport": transport,
            "rate_hz": 5,
            "rss_mb": round(peak / 2**20, 1),
            "cpu_pct": round(100 * used / (t1 - t0), 2),
            "measured_s": round(t1 - t0, 1),
        }
    finally:
        _stop(agent)


def drain(url: str, workdir: Path, outage_s: int = 600, rate_hz: int = 5) -> dict:
    sys.path.insert(0, str(ROOT))
    from vehicle_client.outbox import Outbox

    outbox_path = workdir / "drain.db"
    outbox = Outbox(outbox_path)
    n = outage_s * rate_hz
    start = datetime.now(UTC) - timedelta(seconds=outage_s)
    for i in range(n):
        ts = start + timedelta(seconds=i / rate_hz)
        outbox.append(
            {
                "ts": ts.strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z",
                "lat": 43.94 + i * 1e-7,
                "lon": 15.44,
                "speed_mps": 0.3,
            }
        )
    outbox.close()
    agent = _agent(url, _vehicle(url, "bench-drain"), "bench-drain", outbox_path)
    try:
        t0 = time.monotonic()
        _until(lambda: _rows(outbox_path) <= rate_hz * 3, "the outbox to drain", 600, 0.05)
        elapsed = time.monotonic() - t0
    finally:
        _stop(agent)
    return {"backlog": n, "drained_s": round(elapsed, 2), "samples_per_s": round(n / elapsed)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--warmup-s", type=float, default=10.0)
    ap.add_argument("--measure-s", type=float, default=30.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-agent-") as tmp:
        workdir = Path(tmp)
        server, url = _server(workdir)
        try:
            result = {
                "footprint": footprint(url, workdir, args.warmup_s, args.measure_s),
                "footprint_ws": footprint(url, workdir, args.warmup_s, args.measure_s, "ws"),
                "drain_after_10_min_outage": drain(url, workdir),
                "goals": GOALS,
            }
        finally:
            _stop(server)
    if args.json:
        print(json.dumps(result))
        return
    d = result["drain_after_10_min_outage"]
    for f in (result["footprint"], result["footprint_ws"]):
        print(
            f"agent at 5 Hz over {f['transport']}: RSS {f['rss_mb']} MB (goal <= 60), "
            f"CPU {f['cpu_pct']} % of a core (goal <= 3) over {f['measured_s']} s"
        )
    print(
        f"outbox drain after a 10-min outage: {d['backlog']} samples in {d['drained_s']} s "
        f"= {d['samples_per_s']} samples/s"
    )


if __name__ == "__main__":
    main()
