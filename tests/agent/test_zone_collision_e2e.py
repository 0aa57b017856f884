"""The server's watch, end to end (``harbour.py``): a vehicle pushed into a no-go zone
raises a breach and its failsafe holds it, and two vehicles on crossing courses raise a
collision risk before they meet."""

from __future__ import annotations

from tests.agent.harbour import Harbour, held_within, until_async
from vehicle_client.geo import distance_m
from vehicle_client.sim import Current


async def test_a_vehicle_pushed_into_a_zone_raises_a_breach_and_its_failsafe_holds_it(
    harbour: Harbour,
) -> None:
    h = harbour
    boat = await h.boat(
        "pushed",
        current=Current(east_mps=0.3, north_mps=0.0),
        failsafe={"action": "keep_station", "on_breach": True},
    )
    ring = [boat.at(x, y) for x, y in [(15, -20), (60, -20), (60, 20), (15, 20), (15, -20)]]
    zone = await h.call(
        "POST",
        "/api/zones",
        json={
            "name": "wreck",
            "kind": "no_go",
            "polygon": {"type": "Polygon", "coordinates": [[[p["lon"], p["lat"]] for p in ring]]},
        },
    )
    op = await h.operator(boat)
    r = await h.try_submit(op, boat, "go_to", boat.at(40, 0))
    assert r.status_code == 422 and r.json()["error"]["code"] == "zone_violation"
    assert "wreck" in r.json()["error"]["message"]

    async def breached() -> bool:
        return bool(await h.events(boat, "zone_breach"))

    await until_async(breached, "the breach event")
    (event,) = await h.events(boat, "zone_breach")
    assert event["data"]["zone_id"] == zone["zone_id"] and event["data"]["zone"] == "wreck"
    assert event["data"]["action"] == "keep_station"
    held = await h.command(event["data"]["command_id"])
    assert held["type"] == "keep_station" and held["issued_by"] == "system"

    async def holding_now() -> bool:
        return (await h.command(held["command_id"]))["status"] == "executing"

    await until_async(holding_now, "the failsafe's keep_station executing")
    await held_within(h, boat, metres=3.0, sim_seconds=30.0)


# ---- collision forecast ----------------------------------------------------------------------


async def test_two_vehicles_on_crossing_courses_raise_collision_risk_before_they_meet(
    harbour: Harbour,
) -> None:
    h = harbour
    # a sails east through the crossing point, b north through it, from 60 m off each.
    a = await h.boat("cross-a", time_scale=5.0)
    b_start = a.at(60, -60)
    b = await h.boat("cross-b", start=(b_start["lat"], b_start["lon"]), time_scale=5.0)
    op = await h.operator(a, b)
    crossing = a.at(60, 0)
    await h.submit(op, a, "go_to", a.at(200, 0))
    await h.submit(op, b, "go_to", a.at(60, 200))

    async def risk() -> bool:
        return bool(await h.events(a, "collision_risk"))

    await until_async(risk, "collision_risk")
    (event,) = (await h.events(a, "collision_risk"))[:1]
    assert event["data"]["other_vehicle_id"] == "cross-b"
    assert (await h.events(b, "collision_risk"))[0]["data"]["other_vehicle_id"] == "cross-a"
    data = event["data"]
    assert data["distance_now_m"] > 10 and data["in_s"] > 0, "raised before they met"
    assert data["closest_m"] <= 10  # below the separation, rounded to 0.1 m (9.97 is 10.0)
    assert distance_m(data["lat"], data["lon"], crossing["lat"], crossing["lon"]) < 40
