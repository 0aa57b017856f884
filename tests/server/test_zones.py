"""Operating areas and no-go zones through HTTP: drawn by admins, seen by users, and held
against every command that sends a vehicle somewhere."""

from __future__ import annotations

import json
from collections.abc import AsyncIterator, Callable
from typing import Any

import httpx
import pytest
import shapely
from shapely.geometry import shape

from server.settings import Settings
from tests.factories import ADMIN, make_user
from tests.server.commanding import World, eventually, world
from tests.server.test_obstacles import ORIGIN, at, polygon

pytestmark = pytest.mark.usefixtures("store_backend")

#: A no-go square 40..60 m east, -30..30 m north of ORIGIN.
PIER = [(40.0, -30.0), (60.0, -30.0), (60.0, 30.0), (40.0, 30.0)]
#: An operating area 200 m square round ORIGIN.
BAY = [(-100.0, -100.0), (100.0, -100.0), (100.0, 100.0), (-100.0, 100.0)]


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    async with world(make_settings(safety_radius_m=5, separation_m=10)) as w:
        yield w


async def zone(w: World, body: dict[str, Any], who: dict[str, str] = ADMIN) -> dict[str, Any]:
    r = await w.http.post("/api/zones", headers=who, json=body)
    assert r.status_code == 201, r.text
    made: dict[str, Any] = r.json()
    return made


def no_go(name: str = "pier 3", corners: list[tuple[float, float]] = PIER, **more: Any) -> dict:
    return {"name": name, "kind": "no_go", "polygon": polygon(corners), **more}


def go_to(x: float, y: float) -> dict[str, Any]:
    return {"type": "go_to", "args": at(x, y)}


async def test_zones_are_drawn_listed_changed_and_removed_with_a_rising_version(
    w: World,
) -> None:
    me = await w.vehicle()
    first = await zone(w, no_go(clearance_m=3))
    assert first["zone_id"] and first["kind"] == "no_go" and first["clearance_m"] == 3
    assert first["polygon"] == polygon(PIER) and first["vehicles"] == []
    area = await zone(
        w,
        {
            "name": "bay",
            "kind": "operating_area",
            "polygon": polygon(BAY),
            "vehicles": [me.vehicle_id],
        },
    )
    assert area["version"] > first["version"]
    listed = (await w.http.get("/api/zones", headers=ADMIN)).json()
    assert [z["zone_id"] for z in listed["zones"]] == [first["zone_id"], area["zone_id"]]
    assert listed["version"] == area["version"]
    r = await w.http.patch(f"/api/zones/{first['zone_id']}", headers=ADMIN, json={"name": "pier 4"})
    assert r.status_code == 200 and r.json()["name"] == "pier 4"
    assert r.json()["version"] > listed["version"]
    r = await w.http.delete(f"/api/zones/{first['zone_id']}", headers=ADMIN)
    assert r.status_code == 200
    after = (await w.http.get("/api/zones", headers=ADMIN)).json()
    assert [z["zone_id"] for z in after["zones"]] == [area["zone_id"]]
    assert after["version"] > r.json()["version"] - 1 >= listed["version"]
    events = (
        await w.http.get("/api/events", headers=ADMIN, params={"kind": "zones_changed"})
    ).json()
    actions = sorted(e["data"]["action"] for e in events["events"] if e["vehicle_id"] is None)
    assert actions == ["changed", "created", "created", "deleted"]
    assert (await w.http.delete(f"/api/zones/{first['zone_id']}", headers=ADMIN)).status_code == 404


async def test_a_zone_s_kind_cannot_change_and_a_patch_that_changes_nothing_keeps_it(
    w: World,
) -> None:
    made = await zone(w, no_go(clearance_m=3))
    url = f"/api/zones/{made['zone_id']}"
    w.clock.advance(60)  # a change now would move updated_at
    r = await w.http.patch(url, headers=ADMIN, json={"kind": "operating_area"})
    assert r.status_code == 422, r.text
    assert [d["field"] for d in r.json()["error"]["details"]] == ["kind"]
    assert "cannot change" in r.json()["error"]["message"]
    for same in (
        {},
        {"kind": "no_go"},
        {"name": made["name"], "clearance_m": 3.0, "polygon": made["polygon"], "vehicles": []},
        made,  # the zone as read, sent back whole
    ):
        r = await w.http.patch(url, headers=ADMIN, json=same)
        assert r.status_code == 200, (same, r.text)
        assert r.json() == made, same
    r = await w.http.patch(url, headers=ADMIN, json={"unknown": 1})  # a misspelt field
    assert r.status_code == 422 and r.json()["error"]["details"][0]["field"] == "unknown"
    listed = (await w.http.get("/api/zones", headers=ADMIN)).json()
    assert listed["version"] == made["version"] and listed["zones"] == [made]
    r = await w.http.patch(url, headers=ADMIN, json={"kind": "no_go", "clearance_m": 4})
    assert r.status_code == 200 and r.json()["clearance_m"] == 4
    assert r.json()["version"] == made["version"] + 1
    assert r.json()["updated_at"] > made["updated_at"]


async def test_users_see_only_the_zones_of_their_vehicles(w: World) -> None:
    mine, theirs = await w.vehicle(), await w.vehicle()
    everyone = await zone(w, no_go("reef"))
    their_area = await zone(
        w,
        {
            "name": "theirs",
            "kind": "operating_area",
            "polygon": polygon(BAY),
            "vehicles": [theirs.vehicle_id],
        },
    )
    both = await zone(w, no_go("shared", vehicles=[mine.vehicle_id, theirs.vehicle_id]))
    _, op = await make_user(w.http, "operator", [mine.vehicle_id])
    seen = (await w.http.get("/api/zones", headers=op)).json()["zones"]
    assert [z["zone_id"] for z in seen] == [everyone["zone_id"], both["zone_id"]]
    assert seen[1]["vehicles"] == [mine.vehicle_id]  # not the vehicle they do not see
    r = await w.http.get(f"/api/zones/{their_area['zone_id']}", headers=op)
    assert r.status_code == 404


async def test_only_admins_draw_and_bad_zones_are_422(w: World) -> None:
    _, manager = await make_user(w.http, "manager")
    r = await w.http.post("/api/zones", headers=manager, json=no_go())
    assert r.status_code == 403
    for body, field in [
        ({**no_go(), "kind": "harbour"}, "kind"),
        ({"name": "x", "kind": "operating_area", "polygon": polygon(BAY)}, "vehicles"),
        (no_go(vehicles=["nobody-here"]), "vehicles"),
        ({**no_go(), "polygon": polygon([(0, 0), (10, 10), (10, 0), (0, 10)])}, "polygon"),
        (no_go(clearance_m=-1), "clearance_m"),
    ]:
        r = await w.http.post("/api/zones", headers=ADMIN, json=body)
        assert r.status_code == 422, (body, r.text)
        fields = [d["field"] for d in r.json()["error"]["details"]]
        assert any(f.startswith(field) for f in fields), (field, r.text)
    # a ring across the antimeridian (179 to -179): GeoJSON draws it 358 degrees wide
    across = [[[179.0, 0.0], [-179.0, 0.0], [-179.0, 1.0], [179.0, 1.0], [179.0, 0.0]]]
    body = {**no_go(), "polygon": {"type": "Polygon", "coordinates": across}}
    r = await w.http.post("/api/zones", headers=ADMIN, json=body)
    assert r.status_code == 422, r.text
    assert "antimeridian" in r.json()["error"]["message"]
    assert r.json()["error"]["details"][0]["field"] == "polygon.coordinates.0.1"
    r = await w.http.post("/api/obstacles", headers=ADMIN, json={
        "name": "x", "polygon": {"type": "Polygon", "coordinates": across},
    })  # fmt: skip
    assert r.status_code == 422 and "antimeridian" in r.text, r.text
    raw = json.dumps(no_go()).replace('"name"', '"clearance_m": NaN, "name"')
    r = await w.http.post(
        "/api/zones", headers={**ADMIN, "content-type": "application/json"}, content=raw
    )
    assert r.status_code == 422 and "clearance_m" in r.text


@pytest.mark.parametrize("name", ["z\x1b[2Jx\u202e", "two\nlines", "a\x00b", "Alpha\u2066x"])
async def test_a_zone_name_with_control_or_reordering_characters_is_422(
    w: World, name: str
) -> None:
    """A zone's name is shown on screens as an obstacle's is: refused on create and on a
    patch alike, naming ``name``, and the zone kept as it was."""
    r = await w.http.post("/api/zones", headers=ADMIN, json=no_go(name))
    assert r.status_code == 422, r.text
    assert [d["field"] for d in r.json()["error"]["details"]] == ["name"]
    assert "shown on screens" in r.json()["error"]["details"][0]["message"]
    made = await zone(w, no_go())
    r = await w.http.patch(f"/api/zones/{made['zone_id']}", headers=ADMIN, json={"name": name})
    assert r.status_code == 422, r.text
    assert [d["field"] for d in r.json()["error"]["details"]] == ["name"]
    got = await w.http.get(f"/api/zones/{made['zone_id']}", headers=ADMIN)
    assert got.json()["name"] == "pier 3" and got.json()["version"] == made["version"]


async def test_a_go_to_into_a_no_go_zone_is_refused_naming_it(w: World) -> None:
    made = await zone(w, no_go())
    me = await w.vehicle()
    await w.move_to(me, 1, *ORIGIN)
    op = await w.operator_in_control(me)
    r = await w.submit(op, [me], go_to(50, 0))
    assert r.status_code == 422, r.text
    error = r.json()["error"]
    assert error["code"] == "zone_violation"
    assert "pier 3" in error["message"] and "target" in error["message"]
    assert error["details"][0]["zone_id"] == made["zone_id"]
    # Through it to the far side: refused as well; round it, taken.
    r = await w.submit(op, [me], go_to(100, 0))
    assert r.status_code == 422 and "crosses" in r.json()["error"]["message"]
    assert (await w.submit(op, [me], go_to(0, 80))).status_code == 202
    # keep_station on a point in it, and an unplanned path through it: refused.
    r = await w.submit(op, [me], {"type": "keep_station", "args": at(50, 10)})
    assert r.status_code == 422 and r.json()["error"]["code"] == "zone_violation"
    path = {"type": "follow_path", "args": {"waypoints": [at(0, 50), at(100, 0)]}}
    r = await w.submit(op, [me], path)
    assert r.status_code == 422 and "pier 3" in r.json()["error"]["message"]


async def test_a_failsafe_home_the_zones_refuse_is_422_naming_home(w: World) -> None:
    """The vehicle drives home by itself when its link is lost, where no server checks its
    way: a home in a no-go zone, or out of its operating area, is refused when set."""
    me = await w.vehicle()
    await zone(w, no_go())
    bay = {"name": "bay", "kind": "operating_area", "polygon": polygon(BAY)}
    await zone(w, {**bay, "vehicles": [me.vehicle_id]})

    async def set_home(x: float, y: float) -> httpx.Response:
        body = {"action": "return_home", "home": at(x, y)}
        return await w.http.put(f"/api/vehicles/{me.vehicle_id}/failsafe", headers=ADMIN, json=body)

    for x, y, said in ((50, 0, "home is in no-go zone pier 3"), (500, 0, "home is outside")):
        r = await set_home(x, y)
        assert r.status_code == 422, r.text
        error = r.json()["error"]
        assert error["code"] == "zone_violation" and said in error["message"]
        assert error["details"][0]["field"] == "home"
    assert (await set_home(-50, 0)).status_code == 200


async def test_a_zone_for_other_vehicles_does_not_hold_this_one(w: World) -> None:
    me, other = await w.vehicle(), await w.vehicle()
    await zone(w, no_go(vehicles=[other.vehicle_id]))
    await w.move_to(me, 1, *ORIGIN)
    op = await w.operator_in_control(me)
    assert (await w.submit(op, [me], go_to(50, 0))).status_code == 202


async def test_the_operating_area_holds_its_vehicles(w: World) -> None:
    me, free = await w.vehicle(), await w.vehicle()
    await zone(
        w,
        {
            "name": "bay",
            "kind": "operating_area",
            "polygon": polygon(BAY),
            "vehicles": [me.vehicle_id],
        },
    )
    for v in (me, free):
        await w.move_to(v, 1, *ORIGIN)
    op = await w.operator_in_control(me)
    r = await w.submit(op, [me], go_to(150, 0))
    assert r.status_code == 422
    assert (
        "operating area" in r.json()["error"]["message"] and "bay" in r.json()["error"]["message"]
    )
    assert (await w.submit(op, [me], go_to(90, 90))).status_code == 202
    op2 = await w.operator_in_control(free)
    assert (await w.submit(op2, [free], go_to(150, 0))).status_code == 202


async def test_a_vehicle_in_a_zone_may_be_sent_out_of_it(w: World) -> None:
    await zone(w, no_go())
    me = await w.vehicle()
    lat, lon = at(50, 0).values()
    await w.move_to(me, 1, lat, lon)
    op = await w.operator_in_control(me)
    assert (await w.submit(op, [me], go_to(0, 0))).status_code == 202


async def test_a_planned_path_goes_round_no_go_zones_and_stays_in_the_area(w: World) -> None:
    pier = await zone(w, no_go(clearance_m=3))
    me = await w.vehicle()
    await zone(
        w,
        {
            "name": "channel",
            "kind": "operating_area",
            "polygon": polygon([(-20, -40), (120, -40), (120, 40), (-20, 40)]),
            "vehicles": [me.vehicle_id],
        },
    )
    await w.move_to(me, 1, *ORIGIN)
    op = await w.operator_in_control(me)
    command = {"type": "follow_path", "args": {"waypoints": [at(100, 0)], "plan": True}}
    cmd = await w.command(await w.queued(op, me, command))
    path = cmd["args"]["path"]
    assert path[-1] == pytest.approx(at(100, 0))
    route = shapely.LineString([(ORIGIN[1], ORIGIN[0])] + [(p["lon"], p["lat"]) for p in path])
    assert not route.intersects(shape(pier["polygon"]))
    channel = shape(
        {
            "type": "Polygon",
            "coordinates": polygon([(-20, -40), (120, -40), (120, 40), (-20, 40)])["coordinates"],
        }
    )
    assert channel.covers(route)
    assert cmd["args"]["path_hash"].startswith("sha256:")


async def test_no_way_inside_the_area_is_refused_with_the_reason(w: World) -> None:
    me = await w.vehicle()
    await zone(w, no_go("wall", [(40.0, -60.0), (60.0, -60.0), (60.0, 60.0), (40.0, 60.0)]))
    await zone(
        w,
        {
            "name": "channel",
            "kind": "operating_area",
            "polygon": polygon([(-20, -40), (120, -40), (120, 40), (-20, 40)]),
            "vehicles": [me.vehicle_id],
        },
    )
    await w.move_to(me, 1, *ORIGIN)
    op = await w.operator_in_control(me)
    command = {"type": "follow_path", "args": {"waypoints": [at(100, 0)], "plan": True}}
    r = await w.submit(op, [me], command)
    assert r.status_code == 422, r.text
    assert "no way round" in r.json()["error"]["message"]
    out = {"type": "follow_path", "args": {"waypoints": [at(0, 80)], "plan": True}}
    r = await w.submit(op, [me], out)  # a waypoint out of the area, said plainly
    assert "waypoint 1 is outside the operating area channel" in r.json()["error"]["message"]


async def test_a_queued_command_the_new_zones_refuse_is_cancelled_before_delivery(w: World) -> None:
    me = await w.vehicle()
    await w.move_to(me, 1, *ORIGIN)
    op = await w.operator_in_control(me)
    kept = await w.queued(op, me, go_to(0, 80))
    refused = await w.queued(op, me, go_to(50, 0))
    await zone(w, no_go())
    handed = await w.poll(me)
    assert [c["command_id"] for c in handed] == [kept]
    cmd = await w.command(refused)
    assert cmd["status"] == "cancelled"
    assert cmd["history"][-1]["detail"].startswith("zones_changed: ")
    assert "pier 3" in cmd["history"][-1]["detail"]


async def test_multi_vehicle_plans_keep_the_separation(w: World) -> None:
    a, b = await w.vehicle(), await w.vehicle()
    la, loa = at(0, 0).values()
    lb, lob = at(0, 40).values()
    await w.move_to(a, 1, la, loa)
    await w.move_to(b, 1, lb, lob)
    op = await w.person("operator", a, b)
    for v in (a, b):
        assert (await w.grant(v, op.username)).status_code == 200
    # The same waypoints for both: the second cannot keep 10 m from the first's path.
    same = {"type": "follow_path", "args": {"waypoints": [at(200, 20)], "plan": True}}
    r = await w.submit(op, [a, b], same)
    assert r.status_code == 422
    message = r.json()["error"]["message"]
    assert "the 10 m about the path planned for" in message and "clearance of 0" not in message
    # Crossing courses: the second goes round the first's path.
    crossing = {"type": "follow_path", "args": {"waypoints": [at(100, 40)], "plan": True}}
    r = await w.submit(op, [a], crossing)
    assert r.status_code == 202, r.text


async def test_breaching_a_zone_raises_an_event(w: World) -> None:
    made = await zone(w, no_go())
    me = await w.vehicle()
    await w.move_to(me, 1, *ORIGIN)
    lat, lon = at(50, 0).values()
    await w.move_to(me, 2, lat, lon)

    async def kinds() -> list[str]:
        r = await w.http.get("/api/events", headers=ADMIN, params={"vehicle_id": me.vehicle_id})
        return [e["kind"] for e in r.json()["events"]]

    await eventually(lambda: _has(kinds, "zone_breach"))
    r = await w.http.get(
        "/api/events", headers=ADMIN, params={"vehicle_id": me.vehicle_id, "kind": "zone_breach"}
    )
    (event,) = r.json()["events"]
    assert event["data"]["zone_id"] == made["zone_id"] and event["data"]["zone"] == "pier 3"
    await w.move_to(me, 3, *ORIGIN)
    await eventually(lambda: _has(kinds, "zone_cleared"))


async def _has(kinds: Callable[[], Any], kind: str) -> bool:
    return kind in await kinds()
