"""Issue 14: the planner on a harbour of obstacles, and the collision forecast's cost.

Planning: a ``follow_path`` of 20 waypoints through a 1 km square holding 10, then
100, rectangular obstacles (10 to 60 m a side, 5 m clearance), the waypoints drawn
outside them; one scene per run (seeded: the same scenes every time), timed with no
deadline. The forecast: 1,000 online vehicles over 5 km, speeds 0 to 3 m/s, random
headings, 10 m separation, 60 s ahead; one pass timed, reported also as the share of
one core it takes at one pass a second.

    python -m bench.safety [--runs 3]
"""

from __future__ import annotations

import argparse
import random
import sys
import time

import shapely

from bench import Metric
from server.domain.forecast import Course, forecast
from server.domain.geo import from_local
from server.domain.plan_frame import Zone
from server.domain.planning import plan_path

TITLE = "safety: planning round 10 / 100 obstacles (20 waypoints), forecast of 1,000 vehicles"
ORIGIN = (43.9, 15.4)
CLEARANCE_M = 5.0


def _scene(seed: int, obstacles: int) -> tuple[list[Zone], list[tuple[float, float]]]:
    rng = random.Random(seed)
    boxes: list[shapely.Polygon] = []
    while len(boxes) < obstacles:
        x, y = rng.uniform(-500, 450), rng.uniform(-500, 450)
        w, h = rng.uniform(10, 60), rng.uniform(10, 60)
        box = shapely.box(x, y, x + w, y + h)
        if not any(box.buffer(2 * CLEARANCE_M).intersects(b) for b in boxes):
            boxes.append(box)
    grown = shapely.union_all([b.buffer(CLEARANCE_M + 1) for b in boxes])
    waypoints: list[tuple[float, float]] = []
    while len(waypoints) < 21:  # the start, then 20
        x, y = rng.uniform(-500, 500), rng.uniform(-500, 500)
        if not grown.contains(shapely.Point(x, y)):
            waypoints.append(from_local(x, y, *ORIGIN))
    zones = [
        Zone(
            (tuple(from_local(x, y, *ORIGIN) for x, y in b.exterior.coords),),
            CLEARANCE_M,
            f"o{k}",
        )
        for k, b in enumerate(boxes)
    ]
    return zones, waypoints


def _plan_s(seed: int, obstacles: int) -> float:
    zones, points = _scene(seed, obstacles)
    began = time.perf_counter()
    plan_path(points[0], points[1:], [], zones)
    return time.perf_counter() - began


def _fleet(seed: int, n: int) -> list[Course]:
    rng = random.Random(seed)
    out = []
    for k in range(n):
        lat, lon = from_local(rng.uniform(-2500, 2500), rng.uniform(-2500, 2500), *ORIGIN)
        out.append(Course(f"v{k}", lat, lon, rng.uniform(0, 3), rng.uniform(0, 360)))
    return out


def _forecast_s(seed: int) -> float:
    fleet = _fleet(seed, 1000)
    best = float("inf")
    for _ in range(5):  # the pass, not the interpreter's first call, is what runs each second
        began = time.perf_counter()
        forecast(fleet, horizon_s=60.0, separation_m=10.0)
        best = min(best, time.perf_counter() - began)
    return best


def run(runs: int) -> list[Metric]:
    ten = Metric("plan: 10 obstacles, 20 waypoints", "ms", goal=("max", 50.0))
    hundred = Metric("plan: 100 obstacles, 20 waypoints", "ms", goal=("max", 500.0))
    one_pass = Metric("forecast: one pass, 1,000 vehicles", "ms")
    core = Metric("forecast: share of a core at 1 Hz", "%", goal=("max", 5.0))
    for seed in range(runs):
        ten.values.append(_plan_s(seed, 10) * 1e3)
        hundred.values.append(_plan_s(seed, 100) * 1e3)
        seconds = _forecast_s(seed)
        one_pass.values.append(seconds * 1e3)
        core.values.append(seconds * 100)
    return [ten, hundred, one_pass, core]


def main() -> int:
    parser = argparse.ArgumentParser(description=TITLE)
    parser.add_argument("--runs", type=int, default=3)
    for m in run(parser.parse_args().runs):
        values = ", ".join(f"{v:.2f}" for v in m.values)
        print(f"{m.name}: {values} {m.unit}", file=sys.stdout)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
