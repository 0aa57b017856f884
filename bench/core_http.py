"""Core server figures (issue 2).

(a) ``POST /upper/update_param`` (10 samples a call, and 1: a vehicle at 1 Hz sending
    each sample as it is taken) and ``GET /upper/get_control`` (``wait_s=0``)
    throughput as a ratio to a trivial route of the same app in
    the same process: a real uvicorn in a subprocess, loaded over keep-alive
    connections from this process, each kind in short windows taking turns with the
    others. Goal: ratio >= 0.6.
(b) Ingest through ``TelemetryService.ingest`` (batches of 10, 20 vehicles, the
    writer inserting and making durable meanwhile) with 1,000,000 samples already
    stored; the rate over the first and the last 50,000 samples of each 200,000
    ingested. On the embedded store (goal: >= 10,000 samples/s, flat) and on
    FerretDB 1.24 (SQLite) through the real MongoDB driver, beside it.
(c) A one-hour track of one vehicle among 20 at that size, rendered as the JSON
    answer, on both stores. Goal on the embedded store: <= 250 ms.
"""

from __future__ import annotations

import asyncio
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

import httpx

from bench import Metric
from bench._ferretdb import ferretdb
from bench._load import get, hammer, post_json
from fleet_protocol import Sample, Track
from server.api.track_formats import json_points
from server.services.dead_letters import DeadLetters
from server.services.telemetry import TelemetryService
from server.settings import Settings
from server.storage import open_store
from server.storage.dead_letters import DeadLettersRepo
from server.storage.telemetry import TelemetryRepo

TITLE = "HTTP throughput ratios; ingest and track query at 1 M samples, embedded and FerretDB"
TOKEN = "fct_bench-admin-token-0123456789"
CONNECTIONS = 8
SECONDS = 3.0
#: The short windows each kind's SECONDS are measured in, in turn with the other kinds.
SLICES = 6
VEHICLES = 20
STORED = 1_000_000
#: Samples stored before the side-by-side run on FerretDB (and the embedded store).
STORED_FERRETDB = 100_000
BUCKET = 200
INGEST = 200_000
WINDOW = 50_000
T0 = datetime(2026, 1, 1, tzinfo=UTC)


# ---- (a) HTTP ---------------------------------------------------------------
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_ready(port: int, proc: subprocess.Popen[bytes], deadline_s: float = 60) -> None:
    deadline = time.monotonic() + deadline_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError("the bench server exited at start-up")
        try:
            if httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=1).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.1)
    raise RuntimeError("the bench server did not become ready")


def _vehicles(port: int, count: int) -> list[tuple[str, str]]:
    """(instance_id, vehicle token) for ``count`` fresh vehicles."""
    out = []
    with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=10) as c:
        admin = {"Authorization": f"Bearer {TOKEN}"}
        for i in range(count):
            vid = f"bench-{i}"
            r = c.post(
                "/api/vehicles",
                headers=admin,
                json={"vehicle_id": vid, "name": vid, "vehicle_type": "usv"},
            )
            r.raise_for_status()
            token = r.json()["token"]
            r = c.post(
                "/upper/start_instance",
                headers={"Authorization": f"Bearer {token}"},
                json={"vehicle_id": vid, "capabilities": ["stop"]},
            )
            r.raise_for_status()
            out.append((r.json()["instance_id"], token))
    return out


def _http(runs: int) -> list[Metric]:
    trivial = Metric("trivial route", "req/s")
    update = Metric("update_param (10 samples)", "req/s")
    single = Metric("update_param (1 sample)", "req/s")
    control = Metric("get_control (wait_s=0)", "req/s")
    update_ratio = Metric("update_param / trivial", "ratio", goal=("min", 0.6))
    single_ratio = Metric("update_param (1 sample) / trivial", "ratio", goal=("min", 0.6))
    floor_ratio = Metric("parse-only floor / trivial", "ratio")
    control_ratio = Metric("get_control / trivial", "ratio", goal=("min", 0.6))
    port = _free_port()
    with tempfile.TemporaryDirectory() as tmp:
        proc = subprocess.Popen(
            [sys.executable, "-m", "bench._serve", str(port), tmp, TOKEN],
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        try:
            _wait_ready(port, proc)
            units = _vehicles(port, CONNECTIONS)
            seqs = [0] * CONNECTIONS
            t_req = get("/_bench/trivial")
            c_req = [
                get(
                    f"/upper/get_control?instance_id={iid}&wait_s=0",
                    {"Authorization": f"Bearer {tok}"},
                )
                for iid, tok in units
            ]

            floor_body = _update_body("i-floor", 1)

            def floor_req(i: int, _: int) -> bytes:
                return post_json("/_bench/parse_only", floor_body, {})

            def update_req(i: int, _: int, count: int = 10) -> bytes:
                iid, tok = units[i]
                first = seqs[i] + 1
                seqs[i] += count
                body = _update_body(iid, first, count)
                return post_json("/upper/update_param", body, {"Authorization": f"Bearer {tok}"})

            def single_req(i: int, n: int) -> bytes:
                """A vehicle at 1 Hz: each call carries the one sample taken since the last."""
                return update_req(i, n, 1)

            kinds = {
                "trivial": lambda i, n: t_req,
                "update": update_req,
                "single": single_req,
                "control": lambda i, n: c_req[i],
                "floor": floor_req,
            }

            async def measure() -> None:
                await hammer(port, kinds["trivial"], connections=CONNECTIONS, seconds=1.0)
                for _ in range(runs):
                    # Each kind's SECONDS in SLICES short windows, the kinds taking turns
                    # (the order rotated each turn): the machine's speed, which drifts over
                    # seconds here, weighs on every kind alike within a round.
                    rates = dict.fromkeys(kinds, 0.0)
                    order = list(kinds)
                    for turn in range(SLICES):
                        for name in order[turn % len(order) :] + order[: turn % len(order)]:
                            rate, errors = await hammer(
                                port, kinds[name], connections=CONNECTIONS,
                                seconds=SECONDS / SLICES,
                            )  # fmt: skip
                            if errors:
                                raise RuntimeError(f"bench requests failed ({name}): {errors}")
                            rates[name] += rate / SLICES
                    base = rates["trivial"]
                    trivial.values.append(base)
                    update.values.append(rates["update"])
                    single.values.append(rates["single"])
                    control.values.append(rates["control"])
                    update_ratio.values.append(rates["update"] / base)
                    single_ratio.values.append(rates["single"] / base)
                    control_ratio.values.append(rates["control"] / base)
                    floor_ratio.values.append(rates["floor"] / base)

            asyncio.run(measure())
        finally:
            proc.terminate()
            proc.wait(timeout=30)
    return [
        trivial,
        update,
        single,
        control,
        update_ratio,
        single_ratio,
        control_ratio,
        floor_ratio,
    ]


def _update_body(instance_id: str, first_seq: int, count: int = 10) -> bytes:
    """An update_param body with ``count`` samples numbered from ``first_seq``."""
    now = datetime.now(UTC).isoformat()
    samples = [
        {
            "seq": first_seq + k,
            "ts": now,
            "lat": 43.9,
            "lon": 15.4,
            "speed_mps": 1.2,
            "heading_deg": 90.0,
        }
        for k in range(count)
    ]
    return json.dumps(
        {"instance_id": instance_id, "params": {"mode": "auto"}, "samples": samples}
    ).encode()


# ---- (b), (c) embedded store --------------------------------------------------
def _prefill_buckets(vehicle: str, index: int, per_vehicle: int) -> list[dict[str, object]]:
    """``per_vehicle`` samples at 1 Hz in full buckets, a slow loop around a point."""
    out = []
    for b in range(per_vehicle // BUCKET):
        samples = []
        for k in range(BUCKET):
            seq = b * BUCKET + k + 1
            samples.append(
                {
                    "seq": seq,
                    "ts": T0 + timedelta(seconds=seq),
                    "lat": 43.9 + 0.01 * index + 1e-6 * (seq % 977),
                    "lon": 15.4 + 1e-6 * (seq % 1291),
                    "heading_deg": 90.0,
                    "speed_mps": 1.5,
                }
            )
        out.append(TelemetryRepo.make_bucket(vehicle, samples))
    return out


async def _store_bench(
    runs: int, backend: str, mongo_url: str | None, stored: int, goal: bool
) -> list[Metric]:
    where = f"{backend}, {stored / 1_000_000:g} M stored"
    first = Metric(
        f"ingest, first {WINDOW // 1000}k of {INGEST // 1000}k [{where}]",
        "samples/s",
        goal=("min", 10_000) if goal else None,
    )
    last = Metric(
        f"ingest, last {WINDOW // 1000}k of {INGEST // 1000}k [{where}]",
        "samples/s",
        goal=("min", 10_000) if goal else None,
    )
    track = Metric(
        f"track 1 h of 1 vehicle / 20 [{where}]", "ms", goal=("max", 250) if goal else None
    )
    fill = Metric(f"pre-fill [{where}]", "s")
    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings(
            _env_file=None,
            snapshot_path=Path(tmp) / "s.snapshot",
            mongo_url=mongo_url,
            db_name=f"bench_{os.getpid()}",
        )
        store = open_store(settings)
        await store.load()
        repo = TelemetryRepo(store)
        await repo.ensure_indexes()
        per_vehicle = stored // VEHICLES
        started = time.perf_counter()
        for v in range(VEHICLES):
            buckets = _prefill_buckets(f"v{v}", v, per_vehicle)
            for i in range(0, len(buckets), 50):
                await repo.insert_many(buckets[i : i + 50])
        await store.flush()
        fill.values.append(time.perf_counter() - started)
        dead = DeadLetters(DeadLettersRepo(store), lambda _loop: None, lambda: datetime.now(UTC))
        svc = TelemetryService(settings, store, repo, dead)
        await svc.load()

        start = T0 + timedelta(seconds=min(5 * 3600, per_vehicle - 3601))  # 5 h in
        for _ in range(max(runs, 3)):
            t = time.perf_counter()
            result = await svc.track("v7", start, start + timedelta(hours=1))
            Track(
                vehicle_id="v7",
                points=json_points(result),
                truncated=result.truncated,
                next_from=result.next_from,
            ).model_dump_json()
            track.values.append((time.perf_counter() - t) * 1000)
            assert len(result.points) == 3600, len(result.points)

        async def writer() -> None:
            while True:
                await svc.writer_step()
                await asyncio.sleep(svc.writer_tick_s())

        writing = asyncio.create_task(writer())
        next_seq = [per_vehicle + 1] * VEHICLES
        for _ in range(runs):
            batches = []
            for n in range(INGEST // 10):
                v = n % VEHICLES
                s0 = next_seq[v]
                next_seq[v] += 10
                batches.append(
                    (
                        f"v{v}",
                        [
                            Sample(seq=s, ts=T0 + timedelta(seconds=s), lat=43.9, lon=15.4)
                            for s in range(s0, s0 + 10)
                        ],
                    )
                )
            marks = []
            t = time.perf_counter()
            for n, (vid, batch) in enumerate(batches):
                await svc.ingest(vid, "i", batch)
                await asyncio.sleep(0)  # let the writer run, as the event loop would
                if (n + 1) * 10 in (WINDOW, INGEST - WINDOW, INGEST):
                    marks.append(time.perf_counter())
            first.values.append(WINDOW / (marks[0] - t))
            last.values.append(WINDOW / (marks[2] - marks[1]))
        writing.cancel()
        await asyncio.gather(writing, return_exceptions=True)
        await svc.flush_all()
        await store.close()
    return [fill, first, last, track]


async def _stores(runs: int) -> list[Metric]:
    """The embedded store at 1 M samples (the goals), then it and FerretDB side by side at
    0.1 M: FerretDB 1.24's SQLite backend reads every document of a collection for these
    queries (measured: 0.46 s for 500 buckets), so 1 M stored would take it minutes each."""
    large = await _store_bench(runs, "embedded", None, STORED, goal=True)
    small = await _store_bench(runs, "embedded", None, STORED_FERRETDB, goal=False)
    with tempfile.TemporaryDirectory() as tmp, ferretdb(Path(tmp)) as url:
        on_ferretdb = await _store_bench(runs, "ferretdb", url, STORED_FERRETDB, goal=False)
    return large + [m for pair in zip(small, on_ferretdb, strict=True) for m in pair]


def run(runs: int) -> list[Metric]:
    return _http(runs) + asyncio.run(_stores(runs))
