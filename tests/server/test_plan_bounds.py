"""Planning has bounds (issue 12, finding 5): the review's worst case (one obstacle of
1,000 positions, a path of 1,000 waypoints across it) took more than six minutes of the
server's CPU. Now the inputs are bounded, each submit plans within
``FLEET_PLAN_TIMEOUT_S`` (then 422), and the server answers meanwhile."""

from __future__ import annotations

import asyncio
import math
from collections.abc import AsyncIterator, Callable
from typing import Any

import httpx
import pytest

from fleet_protocol.commands import MAX_WAYPOINTS
from server.domain.geo import from_local
from server.settings import Settings
from tests.factories import ADMIN, make_user, make_vehicle, sample, start_instance
from tests.live import serve
from tests.server.commanding import Vehicle, World, eventually, world

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")

ORIGIN = (43.9, 15.4)
TIMEOUT_S = 1.0
#: What the machine may add to the deadline (the tests share two cores with others).
SLACK_S = 2.0


def at(x: float, y: float) -> dict[str, float]:
    lat, lon = from_local(x, y, *ORIGIN)
    return {"lat": lat, "lon": lon}


def star(positions: int = 1000) -> dict[str, Any]:
    """The review's obstacle: a spiky ring of ``positions`` positions (closed), 100 m
    across, every other corner one a shortest path may bend round."""
    corners = [
        at(
            (100 if k % 2 == 0 else 60) * math.cos(2 * math.pi * k / (positions - 1)),
            (100 if k % 2 == 0 else 60) * math.sin(2 * math.pi * k / (positions - 1)),
        )
        for k in range(positions - 1)
    ]
    ring = [[p["lon"], p["lat"]] for p in [*corners, corners[0]]]
    return {"type": "Polygon", "coordinates": [ring]}


#: Back and forth across the star: every leg must go round it.
ACROSS = [at(-200 if i % 2 == 0 else 200, (i % 7) * 10 - 30) for i in range(MAX_WAYPOINTS)]


def follow(waypoints: list[dict[str, float]]) -> dict[str, Any]:
    return {"type": "follow_path", "args": {"waypoints": waypoints, "plan": True}}


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    settings = make_settings(safety_radius_m=5, plan_timeout_s=TIMEOUT_S, plan_workers=1)
    async with world(settings) as w:
        yield w


async def _beside_the_star(w: World) -> tuple[Vehicle, Any]:
    r = await w.http.post("/api/obstacles", headers=ADMIN, json={"name": "star", "polygon": star()})
    assert r.status_code == 201, r.text
    me = await w.vehicle()
    start = at(-250, 0)
    await w.move_to(me, 1, start["lat"], start["lon"])
    return me, await w.operator_in_control(me)


async def test_the_worst_case_ends_at_the_deadline_with_a_422(w: World) -> None:
    me, op = await _beside_the_star(w)
    loop = asyncio.get_running_loop()
    began = loop.time()
    r = await w.submit(op, [me], follow(ACROSS))
    took = loop.time() - began
    assert r.status_code == 422, r.text
    error = r.json()["error"]
    assert error["code"] == "invalid"
    assert f"not planned within {TIMEOUT_S:g} s (FLEET_PLAN_TIMEOUT_S)" in error["message"]
    assert error["details"][0]["instance_id"] == me.instance_id
    assert took < TIMEOUT_S + SLACK_S, took
    assert await w.poll(me) == []  # nothing was queued


async def test_a_plan_round_the_same_obstacle_works_within_the_default_deadline(
    make_settings: Callable[..., Settings],
) -> None:
    assert Settings(_env_file=None).plan_timeout_s == 5.0
    async with world(make_settings(safety_radius_m=5)) as w:
        me, op = await _beside_the_star(w)
        cid = await w.queued(op, me, follow(ACROSS[1:2]))
        path = (await w.command(cid))["args"]["path"]
    assert path[-1] == pytest.approx(ACROSS[1])
    assert len(path) > 1  # round the star


async def test_the_server_answers_while_a_worst_case_plan_runs(
    make_settings: Callable[..., Settings],
) -> None:
    """Over real sockets (uvicorn), so that every answer needs the event loop."""
    settings = make_settings(safety_radius_m=5, plan_timeout_s=3 * TIMEOUT_S, plan_workers=1)
    async with serve(settings) as base, httpx.AsyncClient(base_url=base, timeout=30) as http:
        r = await http.post("/api/obstacles", headers=ADMIN, json={"name": "s", "polygon": star()})
        assert r.status_code == 201, r.text
        vid, vh = await make_vehicle(http)
        iid = (await start_instance(http, vid, vh))["instance_id"]
        start = at(-250, 0)
        there = {"instance_id": iid, "samples": [sample(1, lat=start["lat"], lon=start["lon"])]}
        assert (await http.post("/upper/update_param", headers=vh, json=there)).status_code == 200
        op, op_h = await make_user(http, "operator", [vid])
        grant = {"instance_id": iid, "user": op, "duration_s": 600}
        assert (
            await http.post("/client/grant_control", headers=ADMIN, json=grant)
        ).status_code == 200
        other, other_h = await make_vehicle(http)
        other_iid = (await start_instance(http, other, other_h))["instance_id"]
        body = {"instance_ids": [iid], "command": follow(ACROSS)}
        submit = asyncio.create_task(http.post("/client/submit_control", headers=op_h, json=body))
        await _planning_under_way(http)
        loop = asyncio.get_running_loop()
        for seq in range(2, 7):
            began = loop.time()
            assert (await http.get("/healthz")).status_code == 200
            r = await http.post(
                "/upper/update_param",
                headers=other_h,
                json={"instance_id": other_iid, "samples": [sample(seq)]},
            )
            assert r.status_code == 200, r.text
            assert loop.time() - began < 0.5
        assert not submit.done()  # all that while it planned
        assert (await submit).status_code == 422


async def test_more_waypoints_than_the_limit_are_422_naming_the_field(w: World) -> None:
    me = await w.vehicle()
    op = await w.operator_in_control(me)
    r = await w.submit(op, [me], follow([at(i, 0) for i in range(MAX_WAYPOINTS + 1)]))
    assert r.status_code == 422
    detail = r.json()["error"]["details"][0]
    assert detail["field"] == "command.args.waypoints"
    assert f"at most {MAX_WAYPOINTS}" in detail["message"]


async def _planning_under_way(http: httpx.AsyncClient) -> None:
    """Until the server's /metrics counts a plan under way (a deadline loop)."""

    async def planning() -> bool:
        return "fleet_plans_running 1.0" in (await http.get("/metrics")).text

    await eventually(planning)
