"""Known fixed obstacles through HTTP: admins draw them, users read them, plans avoid them."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from datetime import datetime, timedelta
from typing import Any

import httpx
import pytest
import shapely
from asgi_lifespan import LifespanManager
from shapely.geometry import shape

from fleet_protocol import format_ts
from server.app import create_app
from server.domain.geo import from_local
from server.settings import Settings
from tests.factories import ADMIN, FakeClock, make_user
from tests.server.commanding import World, world

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")

ORIGIN = (43.9, 15.4)


def at(x: float, y: float) -> dict[str, float]:
    lat, lon = from_local(x, y, *ORIGIN)
    return {"lat": lat, "lon": lon}


def polygon(corners: list[tuple[float, float]]) -> dict[str, Any]:
    """A GeoJSON Polygon from corners in metres east, north of ORIGIN (the ring closed)."""
    ring = [[at(x, y)["lon"], at(x, y)["lat"]] for x, y in [*corners, corners[0]]]
    return {"type": "Polygon", "coordinates": [ring]}


PIER = [(40.0, -30.0), (60.0, -30.0), (60.0, 30.0), (40.0, 30.0)]
BUOY = [(-60.0, -5.0), (-50.0, -5.0), (-50.0, 5.0), (-60.0, 5.0)]


async def create(http: httpx.AsyncClient, body: dict[str, Any]) -> httpx.Response:
    return await http.post("/api/obstacles", headers=ADMIN, json=body)


async def test_create_list_and_delete(client: httpx.AsyncClient) -> None:
    r = await create(client, {"name": "pier 3", "polygon": polygon(PIER), "clearance_m": 4})
    assert r.status_code == 201, r.text
    made = r.json()
    assert made["obstacle_id"] and made["created_at"].endswith("Z")
    assert made["name"] == "pier 3" and made["clearance_m"] == 4
    assert made["polygon"] == polygon(PIER)
    _, op = await make_user(client, "operator")
    listed = await client.get("/api/obstacles", headers=op)
    assert listed.status_code == 200
    assert listed.json() == {"obstacles": [made]}
    gone = await client.delete(f"/api/obstacles/{made['obstacle_id']}", headers=ADMIN)
    assert gone.status_code == 200
    assert (await client.get("/api/obstacles", headers=op)).json() == {"obstacles": []}
    again = await client.delete(f"/api/obstacles/{made['obstacle_id']}", headers=ADMIN)
    assert again.status_code == 404
    assert again.json()["error"]["code"] == "not_found"


async def test_the_clearance_defaults_to_the_safety_radius(client: httpx.AsyncClient) -> None:
    r = await create(client, {"name": "reef", "polygon": polygon(PIER)})
    assert r.status_code == 201
    assert r.json()["clearance_m"] == 5.0


async def test_only_admins_draw_and_remove_and_only_users_read(client: httpx.AsyncClient) -> None:
    _, op = await make_user(client, "operator")
    r = await client.post(
        "/api/obstacles", headers=op, json={"name": "x", "polygon": polygon(PIER)}
    )
    assert r.status_code == 403
    assert r.json()["error"]["code"] == "forbidden"
    made = (await create(client, {"name": "x", "polygon": polygon(PIER)})).json()
    r = await client.delete(f"/api/obstacles/{made['obstacle_id']}", headers=op)
    assert r.status_code == 403
    assert (await client.get("/api/obstacles")).status_code == 401


def _bowtie() -> dict[str, Any]:
    return polygon([(0, 0), (10, 10), (10, 0), (0, 10)])


def _with_ring(ring: list[list[float]]) -> dict[str, Any]:
    return {"type": "Polygon", "coordinates": [ring]}


BAD_POLYGONS = [
    pytest.param(_bowtie(), "Self-intersection", id="self-intersecting"),
    pytest.param(
        {
            "type": "Polygon",
            "coordinates": [
                polygon(PIER)["coordinates"][0],
                [[15.0, 43.0], [15.1, 43.0], [15.1, 43.1], [15.0, 43.0]],
            ],
        },
        "Hole lies outside shell",
        id="hole outside",
    ),
    pytest.param(
        _with_ring([[15.4, 43.9], [15.5, 43.9], [15.5, 44.0], [15.4, 44.1]]),
        "not closed",
        id="open ring",
    ),
    pytest.param(
        _with_ring([[15.4, 43.9], [15.5, 43.9], [15.4, 43.9]]), "at least 4", id="too few"
    ),
    pytest.param(
        _with_ring([[15.4, 43.9], [15.5, 93.9], [15.5, 44.0], [15.4, 43.9]]),
        "less than or equal to 90",
        id="latitude out of range",
    ),
    pytest.param(
        _with_ring([[195.4, 43.9], [15.5, 43.9], [15.5, 44.0], [195.4, 43.9]]),
        "less than or equal to 180",
        id="longitude out of range",
    ),
    pytest.param(
        _with_ring(
            [[15.4 + i * 1e-4, 43.9 + (i % 2) * 1e-4] for i in range(1000)] + [[15.4, 43.9]]
        ),
        "at most 1000",
        id="too many vertices",
    ),
    pytest.param({"type": "Point", "coordinates": [15.4, 43.9]}, "Polygon", id="not a polygon"),
    pytest.param({"type": "Polygon", "coordinates": []}, "at least 1", id="no rings"),
]


@pytest.mark.parametrize(("geometry", "reason"), BAD_POLYGONS)
async def test_a_bad_polygon_is_422_with_the_reason(
    client: httpx.AsyncClient, geometry: dict[str, Any], reason: str
) -> None:
    r = await create(client, {"name": "bad", "polygon": geometry})
    assert r.status_code == 422, r.text
    error = r.json()["error"]
    assert error["code"] == "invalid"
    assert any(reason in d["message"] for d in error["details"]), error
    assert all(d["field"].startswith("polygon") for d in error["details"]), error


@pytest.mark.parametrize(
    "body",
    [
        {"polygon": polygon(PIER)},
        {"name": "", "polygon": polygon(PIER)},
        {"name": "x", "polygon": polygon(PIER), "clearance_m": -1},
        {"name": "x"},
    ],
    ids=["no name", "empty name", "negative clearance", "no polygon"],
)
async def test_other_bad_fields_are_422(client: httpx.AsyncClient, body: dict[str, Any]) -> None:
    r = await create(client, body)
    assert r.status_code == 422
    assert r.json()["error"]["code"] == "invalid"


@pytest.fixture
async def one_obstacle_app(
    make_settings: Callable[..., Settings],
) -> AsyncIterator[httpx.AsyncClient]:
    app = create_app(make_settings(max_obstacles=1))
    async with LifespanManager(app) as manager:
        transport = httpx.ASGITransport(app=manager.app)
        async with httpx.AsyncClient(transport=transport, base_url="http://test") as c:
            yield c


async def test_the_number_of_obstacles_is_bounded(one_obstacle_app: httpx.AsyncClient) -> None:
    assert (
        await create(one_obstacle_app, {"name": "a", "polygon": polygon(PIER)})
    ).status_code == 201
    r = await create(one_obstacle_app, {"name": "b", "polygon": polygon(PIER)})
    assert r.status_code == 409
    assert "FLEET_MAX_OBSTACLES" in r.json()["error"]["message"]


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    async with world(make_settings(safety_radius_m=5)) as w:
        yield w


async def test_a_planned_path_goes_round_a_created_obstacle(w: World) -> None:
    pier = polygon(PIER)
    r = await create(w.http, {"name": "pier 3", "polygon": pier, "clearance_m": 3})
    assert r.status_code == 201
    me = await w.vehicle()
    await w.move_to(me, 1, *ORIGIN)
    op = await w.operator_in_control(me)
    goal = at(100, 0)
    command = {"type": "follow_path", "args": {"waypoints": [goal], "plan": True}}
    r = await w.submit(op, [me], command)
    assert r.status_code == 202 and r.json()["warnings"] == []  # planned: nothing to say
    path = (await w.command(r.json()["commands"][0]["command_id"]))["args"]["path"]
    assert path[-1] == pytest.approx(goal)
    assert len(path) > 1  # the straight line crosses the pier: a detour
    route = shapely.LineString([(ORIGIN[1], ORIGIN[0])] + [(p["lon"], p["lat"]) for p in path])
    assert not route.intersects(shape(pier))


async def test_a_waypoint_inside_a_created_obstacle_is_422(w: World) -> None:
    await create(w.http, {"name": "pier 3", "polygon": polygon(PIER)})
    me = await w.vehicle()
    op = await w.operator_in_control(me)
    command = {"type": "follow_path", "args": {"waypoints": [at(-30, 0), at(50, 0)], "plan": True}}
    r = await w.submit(op, [me], command)
    assert r.status_code == 422
    error = r.json()["error"]
    assert error["code"] == "invalid"
    assert "pier 3" in error["message"]
    assert "waypoint 2" in error["message"]  # as the console numbers them
    # the field counts from 0, as every field path does
    assert [d["fields"] for d in error["details"]] == [["command.args.waypoints.1"]]


async def test_a_straight_way_into_a_known_obstacle_is_queued_and_said(w: World) -> None:
    """A go_to, or a path not planned, is the operator's to draw: queued as asked, and the
    obstacle its straight way runs into named in the answer's warnings."""
    await create(w.http, {"name": "pier 3", "polygon": polygon(PIER)})
    me = await w.vehicle()
    await w.move_to(me, 1, *ORIGIN)
    op = await w.operator_in_control(me)
    for command in (
        {"type": "go_to", "args": at(100, 0)},
        {"type": "follow_path", "args": {"waypoints": [at(100, 0)]}},
    ):
        r = await w.submit(op, [me], command)
        assert r.status_code == 202, r.text
        [warning] = r.json()["warnings"]
        assert "runs into pier 3" in warning and "plan: true" in warning
    clear = await w.submit(op, [me], {"type": "go_to", "args": at(0, 100)})  # north: clear
    assert clear.json()["warnings"] == []


async def test_the_obstacles_of_a_past_time_or_window_are_read_back(
    clocked_client: httpx.AsyncClient, clock: FakeClock
) -> None:
    """A replay draws the obstacles there were at its time: a pier removed since is still
    read at a time before its removal, with when it was removed; one drawn later is not."""
    http = clocked_client
    start = clock()
    clock.advance(10)
    pier = (await create(http, {"name": "pier", "polygon": polygon(PIER)})).json()
    clock.advance(10)
    buoy = (await create(http, {"name": "buoy", "polygon": polygon(BUOY)})).json()
    clock.advance(10)
    both = clock()
    clock.advance(10)
    assert (await http.delete(f"/api/obstacles/{pier['obstacle_id']}", headers=ADMIN)).is_success
    removed = clock()
    clock.advance(10)
    _, viewer = await make_user(http, "viewer")

    async def names(**query: datetime) -> list[tuple[str, str | None]]:
        params = {k.rstrip("_"): format_ts(v) for k, v in query.items()}
        r = await http.get("/api/obstacles", headers=viewer, params=params)
        assert r.status_code == 200, r.text
        return [(o["name"], o["deleted_at"]) for o in r.json()["obstacles"]]

    gone = format_ts(removed)
    assert await names() == [("buoy", None)]
    assert await names(at=start) == []
    assert await names(at=both) == [("pier", gone), ("buoy", None)]
    assert await names(at=removed) == [("buoy", None)]  # removed then: not there any more
    assert await names(from_=start, to=both) == [("pier", gone), ("buoy", None)]
    assert await names(from_=removed, to=clock()) == [("buoy", None)]
    assert buoy["deleted_at"] is None
    for params, field in (
        ({"from": format_ts(start)}, "to"),
        ({"to": format_ts(start)}, "from"),
        ({"at": format_ts(start), "from": format_ts(start), "to": format_ts(both)}, "at"),
        ({"from": format_ts(both), "to": format_ts(start)}, "to"),
        ({"at": "yesterday"}, "at"),
    ):
        r = await http.get("/api/obstacles", headers=viewer, params=params)
        assert r.status_code == 422, (params, r.text)
        assert field in r.text, (params, r.text)


async def test_retention_forgets_removed_obstacles_only(
    make_settings: Callable[..., Settings], clock: FakeClock
) -> None:
    app = create_app(make_settings(retention_s=3600), clock=clock)
    async with LifespanManager(app) as manager:
        transport = httpx.ASGITransport(app=manager.app)
        async with httpx.AsyncClient(transport=transport, base_url="http://test") as http:
            old = (await create(http, {"name": "old", "polygon": polygon(PIER)})).json()
            clock.advance(1)
            kept = (await create(http, {"name": "kept", "polygon": polygon(BUOY)})).json()
            await http.delete(f"/api/obstacles/{old['obstacle_id']}", headers=ADMIN)
            before = clock()
            services = app.state.services
            clock.advance(1800)
            await services.obstacles.repo.drop_removed_before(clock() - timedelta(seconds=3600))
            r = await http.get("/api/obstacles", headers=ADMIN, params={"at": format_ts(before)})
            assert [o["name"] for o in r.json()["obstacles"]] == ["kept"]  # removed by then
            window = {"from": format_ts(before - timedelta(seconds=1)), "to": format_ts(before)}
            r = await http.get("/api/obstacles", headers=ADMIN, params=window)
            assert [o["name"] for o in r.json()["obstacles"]] == ["old", "kept"]
            clock.advance(3600)
            await services.obstacles.repo.drop_removed_before(clock() - timedelta(seconds=3600))
            r = await http.get("/api/obstacles", headers=ADMIN, params=window)
            assert [o["name"] for o in r.json()["obstacles"]] == ["kept"]
            assert kept["deleted_at"] is None
