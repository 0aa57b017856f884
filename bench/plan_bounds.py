"""Issue 12, finding 5: the review's worst plan, and what the server does meanwhile.

One star-shaped obstacle of 1,000 positions, a ``follow_path`` of 1,000
waypoints back and forth across it (``tests/server/test_plan_bounds.py`` builds
both). Measured: the planner's time per leg (ten legs, no deadline); the time
to ``OutOfTime`` with a 5 s deadline; then through HTTP on uvicorn with
``FLEET_PLAN_TIMEOUT_S=5``: the time to the 422, and ``/healthz`` and
``update_param`` answered meanwhile, against ``/healthz`` idle.

    python -m bench.plan_bounds [--runs 3]
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import sys
import tempfile
import time
from pathlib import Path

import httpx

from bench import Metric
from server.domain.planning import Deadline, OutOfTime, plan_path
from server.services.obstacles import zone_of
from server.settings import Settings
from tests.factories import ADMIN, ADMIN_TOKEN, make_user, make_vehicle, sample, start_instance
from tests.live import serve
from tests.server.test_plan_bounds import ACROSS, at, follow, star

TITLE = "planning: the review's worst case (1,000-position obstacle, 1,000 waypoints)"
TIMEOUT_S = 5.0


def _planner_alone(leg_s: Metric, stopped_s: Metric) -> None:
    zone = zone_of({"polygon": star(), "clearance_m": 5.0, "name": "star"})
    start = at(-250, 0)
    origin = (start["lat"], start["lon"])
    waypoints = [(p["lat"], p["lon"]) for p in ACROSS]
    began = time.perf_counter()
    plan_path(origin, waypoints[1:11], [], [zone])
    leg_s.values.append((time.perf_counter() - began) / 10)
    began = time.perf_counter()
    try:
        plan_path(
            origin, waypoints, [], [zone], Deadline(time.monotonic() + TIMEOUT_S, time.monotonic)
        )
    except OutOfTime:
        stopped_s.values.append(time.perf_counter() - began)


async def _over_http(
    answer_s: Metric, idle_ms: Metric, health_ms: Metric, ingest_ms: Metric
) -> None:
    with tempfile.TemporaryDirectory() as directory:
        settings = Settings(
            _env_file=None,
            snapshot_path=Path(directory) / "bench.snapshot",
            admin_token=ADMIN_TOKEN,
            rate_limit_per_s=1e9,
            rate_limit_burst=10**9,
            safety_radius_m=5,
            plan_timeout_s=TIMEOUT_S,
        )
        async with serve(settings) as base, httpx.AsyncClient(base_url=base, timeout=60) as http:
            assert (
                await http.post(
                    "/api/obstacles", headers=ADMIN, json={"name": "s", "polygon": star()}
                )
            ).is_success
            vid, vh = await make_vehicle(http)
            iid = (await start_instance(http, vid, vh))["instance_id"]
            here = at(-250, 0)
            there = {"instance_id": iid, "samples": [sample(1, lat=here["lat"], lon=here["lon"])]}
            assert (await http.post("/upper/update_param", headers=vh, json=there)).is_success
            op, op_h = await make_user(http, "operator", [vid])
            grant = {"instance_id": iid, "user": op, "duration_s": 600}
            assert (await http.post("/client/grant_control", headers=ADMIN, json=grant)).is_success
            other, other_h = await make_vehicle(http)
            other_iid = (await start_instance(http, other, other_h))["instance_id"]
            loop = asyncio.get_running_loop()
            idle = []
            for _ in range(50):
                began = loop.time()
                await http.get("/healthz")
                idle.append(loop.time() - began)
            body = {"instance_ids": [iid], "command": follow(ACROSS)}
            began_submit = loop.time()
            submit = asyncio.create_task(
                http.post("/client/submit_control", headers=op_h, json=body)
            )
            health, ingest, seq = [], [], 1
            while not submit.done():
                began = loop.time()
                await http.get("/healthz")
                health.append(loop.time() - began)
                seq += 1
                began = loop.time()
                sent = {"instance_id": other_iid, "samples": [sample(seq)]}
                assert (
                    await http.post("/upper/update_param", headers=other_h, json=sent)
                ).is_success
                ingest.append(loop.time() - began)
            assert (await submit).status_code == 422
            answer_s.values.append(loop.time() - began_submit)
            idle_ms.values.append(statistics.median(idle) * 1e3)
            health_ms.values.append(statistics.median(health) * 1e3)
            ingest_ms.values.append(statistics.median(ingest) * 1e3)


def run(runs: int) -> list[Metric]:
    leg_s = Metric("planner: one leg round the star", "s")
    stopped_s = Metric(
        f"planner: 1,000 waypoints, {TIMEOUT_S:g} s deadline", "s", goal=("max", TIMEOUT_S + 0.3)
    )
    answer_s = Metric(
        f"HTTP: the 422 (FLEET_PLAN_TIMEOUT_S={TIMEOUT_S:g})", "s", goal=("max", TIMEOUT_S + 0.5)
    )
    idle_ms = Metric("HTTP: /healthz, idle (median)", "ms")
    health_ms = Metric("HTTP: /healthz while it plans (median)", "ms", goal=("max", 50.0))
    ingest_ms = Metric("HTTP: update_param while it plans (median)", "ms", goal=("max", 50.0))
    for _ in range(runs):
        _planner_alone(leg_s, stopped_s)
        asyncio.run(_over_http(answer_s, idle_ms, health_ms, ingest_ms))
    return [leg_s, stopped_s, answer_s, idle_ms, health_ms, ingest_ms]


def main() -> int:
    parser = argparse.ArgumentParser(description=TITLE)
    parser.add_argument("--runs", type=int, default=3)
    for m in run(parser.parse_args().runs):
        values = ", ".join(f"{v:.3f}" for v in m.values)
        print(f"{m.name}: {values} {m.unit}", file=sys.stdout)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
