"""Instances and presence through /upper and /client."""

from __future__ import annotations

from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any

import httpx
import pytest

from fleet_protocol import parse_ts
from server.settings import Settings
from tests.factories import ADMIN, FakeClock, make_user, make_vehicle, sample, start_instance
from tests.live import call, connect, recv_until, serve
from tests.server.commanding import eventually

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


async def test_start_returns_the_contract_fields(client: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(client)
    body = await start_instance(client, vid, vh)
    assert body["resumed"] is False
    assert body["last_seq"] == 0
    for key in (
        "instance_id",
        "heartbeat_interval_s",
        "stale_after_s",
        "offline_after_s",
        "ack_timeout_s",
        "server_time",
        "failsafe",
        "control",
    ):
        assert key in body
    assert body["failsafe"]["after_s"] == 30.0 and body["failsafe"]["action"] == "keep_station"
    assert body["server_time"].endswith("Z")


async def test_returning_vehicle_resumes_its_instance(
    clocked_client: httpx.AsyncClient, clock: FakeClock
) -> None:
    client = clocked_client
    vid, vh = await make_vehicle(client)
    first = await start_instance(client, vid, vh)
    clock.advance(3600)  # long out of contact: offline, still reserved
    view = (await client.get(f"/api/vehicles/{vid}", headers=ADMIN)).json()
    assert view["presence"] == "offline" and view["instance_id"] == first["instance_id"]
    again = await start_instance(client, vid, vh)
    assert again["resumed"] is True and again["instance_id"] == first["instance_id"]


async def test_presence_moves_by_heartbeat_age(
    clocked_client: httpx.AsyncClient, clock: FakeClock
) -> None:
    client = clocked_client
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]

    async def presence() -> str:
        r = await client.post("/client/connect_instance", headers=ADMIN, json={"instance_id": iid})
        return str(r.json()["instance"]["presence"])

    assert await presence() == "online"
    clock.advance(5)
    assert await presence() == "stale"
    clock.advance(10)
    assert await presence() == "offline"
    r = await client.post("/upper/heartbeat", headers=vh, json={"instance_id": iid})
    assert r.status_code == 200 and r.json()["ok"] is True
    assert await presence() == "online"


async def test_finish_is_for_good(client: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    r = await client.post("/upper/finish_instance", headers=vh, json={"instance_id": iid})
    assert r.json() == {"instance_id": iid, "state": "finished"}
    again = await client.post("/upper/heartbeat", headers=vh, json={"instance_id": iid})
    assert again.status_code == 409
    assert again.json()["error"]["code"] == "instance_finished"
    view = await client.post("/client/connect_instance", headers=ADMIN, json={"instance_id": iid})
    assert view.json()["instance"]["presence"] == "finished"
    fresh = await start_instance(client, vid, vh)
    assert fresh["resumed"] is False and fresh["instance_id"] != iid


async def test_finish_is_contact_too(clocked_client: httpx.AsyncClient, clock: FakeClock) -> None:
    """Every /upper/* call moves last_seen, finish_instance too (it did not)."""
    client = clocked_client
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    clock.advance(3)
    r = await client.post("/upper/finish_instance", headers=vh, json={"instance_id": iid})
    assert r.status_code == 200, r.text
    view = await client.post("/client/connect_instance", headers=ADMIN, json={"instance_id": iid})
    assert parse_ts(view.json()["instance"]["last_seen"]) == clock()


async def test_unknown_instance_is_404(client: httpx.AsyncClient) -> None:
    _, vh = await make_vehicle(client)
    r = await client.post("/upper/heartbeat", headers=vh, json={"instance_id": "i-nope"})
    assert r.status_code == 404 and r.json()["error"]["code"] == "not_found"


async def test_unregistered_vehicle_cannot_start(client: httpx.AsyncClient) -> None:
    _, vh = await make_vehicle(client)
    r = await client.post("/upper/start_instance", headers=vh, json={"vehicle_id": "ghost"})
    assert r.status_code == 403


async def test_another_vehicles_instance_is_404(client: httpx.AsyncClient) -> None:
    v1, h1 = await make_vehicle(client)
    _, h2 = await make_vehicle(client)
    iid = (await start_instance(client, v1, h1))["instance_id"]
    r = await client.post("/upper/heartbeat", headers=h2, json={"instance_id": iid})
    assert r.status_code == 404  # as an unknown one: its existence is not told
    assert r.json()["error"] == {
        "code": "not_found",
        "message": f"no instance {iid}",
        "details": None,
    }


async def test_a_sample_dated_years_ahead_is_stored_but_never_the_position(
    client: httpx.AsyncClient,
) -> None:
    """A GPS or clock glitch (2099) would otherwise hold the vehicle's position until then,
    and every later sample would read as replayed; it is stored as sent."""
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    now = datetime.now(UTC)
    glitch = sample(1, ts=datetime(2099, 12, 31, tzinfo=UTC), lat=1.0, lon=1.0)
    real = sample(2, ts=now, lat=43.95, lon=15.45)
    for s in (glitch, real):
        body = {"instance_id": iid, "samples": [s]}
        assert (await client.post("/upper/update_param", headers=vh, json=body)).is_success
    got = (await client.get(f"/api/vehicles/{vid}", headers=ADMIN)).json()
    assert (got["position"]["seq"], got["position"]["lat"]) == (2, 43.95)
    stored = await client.get(f"/api/vehicles/{vid}/telemetry", headers=ADMIN)
    assert [s["seq"] for s in stored.json()["samples"]] == [1, 2]


async def test_a_sample_dated_years_ahead_is_said_so_to_those_watching_the_vehicle(
    make_settings: Callable[..., Settings],
) -> None:
    """The console took it as the newest position and kept the marker there: no later
    sample could replace it. The live event says it is not the position."""
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as api:
        vid, vh = await make_vehicle(api)
        iid = (await start_instance(api, vid, vh))["instance_id"]
        async with await connect(base, "/ws/client", ADMIN["Authorization"][7:]) as ws:
            await call(ws, "subscribe", "s", topics=[f"vehicle/{vid}/telemetry"])
            glitch = sample(1, ts=datetime(2099, 12, 31, tzinfo=UTC), lat=1.0, lon=1.0)
            real = sample(2, ts=datetime.now(UTC), lat=43.95, lon=15.45)
            body = {"instance_id": iid, "samples": [glitch, real]}
            assert (await api.post("/upper/update_param", headers=vh, json=body)).is_success
            said = []
            while len(said) < 2:
                frame = await recv_until(ws, lambda f: f.get("op") == "event")
                if not frame.get("snapshot"):
                    said.append(frame["data"])
    assert [(s["seq"], s.get("ahead")) for s in said] == [(1, True), (2, None)]


async def test_a_samples_nulls_and_unknown_fields_are_not_taken_into_what_watchers_see(
    make_settings: Callable[..., Settings],
) -> None:
    """update_param reads its samples as plain dicts: a field sent as null is left out
    (as the model's ``exclude_none`` left it), a field the contract lacks is ignored."""
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as api:
        vid, vh = await make_vehicle(api)
        iid = (await start_instance(api, vid, vh))["instance_id"]
        async with await connect(base, "/ws/client", ADMIN["Authorization"][7:]) as ws:
            await call(ws, "subscribe", "s", topics=[f"vehicle/{vid}/telemetry"])
            sent = {
                **sample(1, ts=datetime(2026, 11, 27, 6, 0, 0, 250000, tzinfo=UTC)),
                "depth_m": None,
                "data": None,
                "battery_pct": 81.5,
                "colour": "red",
            }
            body = {"instance_id": iid, "samples": [sent]}
            r = await api.post("/upper/update_param", headers=vh, json=body)
            assert r.status_code == 200 and r.json()["accepted"] == 1, r.text
            frame = await recv_until(ws, lambda f: f.get("op") == "event" and not f.get("snapshot"))
    said = frame["data"]
    assert said["ts"] == "2026-11-27T06:00:00.250Z" and said["battery_pct"] == 81.5
    assert not {"depth_m", "data", "colour"} & set(said), said


async def test_viewer_sees_only_assigned_vehicles(client: httpx.AsyncClient) -> None:
    v1, _h1 = await make_vehicle(client)
    v2, h2 = await make_vehicle(client)
    i2 = (await start_instance(client, v2, h2))["instance_id"]
    _, viewer = await make_user(client, "viewer", [v1])
    listed = (await client.get("/api/vehicles", headers=viewer)).json()["vehicles"]
    assert [v["vehicle_id"] for v in listed] == [v1]
    assert listed[0]["presence"] == "offline" and listed[0]["instance_id"] is None
    r = await client.get("/client/get_param", headers=viewer, params={"instance_id": i2})
    assert r.status_code == 404
    r = await client.post("/client/connect_instance", headers=viewer, json={"vehicle_id": v2})
    assert r.status_code == 404


async def test_connect_by_vehicle_id(client: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh, capabilities=["stop", "go_to"]))["instance_id"]
    r = await client.post("/client/connect_instance", headers=ADMIN, json={"vehicle_id": vid})
    inst = r.json()["instance"]
    assert inst["instance_id"] == iid and inst["capabilities"] == ["stop", "go_to"]
    assert inst["control_mode"] == "idle" and inst["control"] is None


async def test_events_record_instance_life(client: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(client)
    await start_instance(client, vid, vh)
    r = await client.get("/api/events", headers=ADMIN, params={"vehicle_id": vid})
    kinds = [(e["kind"], e["data"].get("action")) for e in r.json()["events"]]
    assert ("instance", "started") in kinds


async def test_an_events_window_that_ends_before_it_begins_is_422_as_a_tracks(
    client: httpx.AsyncClient,
) -> None:
    vid, vh = await make_vehicle(client)
    await start_instance(client, vid, vh)
    for params in (
        {"from": "2100-01-01T00:00:00Z", "to": "1970-01-01T00:00:00Z"},
        {"from": "2026-01-01T00:00:00Z", "to": "2026-01-01T00:00:00Z"},
    ):
        for path in ("/api/events", f"/api/vehicles/{vid}/track"):
            r = await client.get(path, headers=ADMIN, params=params)
            assert r.status_code == 422, (path, params, r.text)
            assert r.json()["error"]["details"] == [
                {"field": "from", "message": "must be earlier than to"}
            ]
    r = await client.get("/api/events", headers=ADMIN, params={"from": "2026-01-01T00:00:00Z"})
    assert r.status_code == 200 and r.json()["events"]
    # A from still to come and no to: nothing yet (a log followed by a clock a little ahead).
    r = await client.get("/api/events", headers=ADMIN, params={"from": "2099-01-01T00:00:00Z"})
    assert r.status_code == 200 and r.json()["events"] == []


async def test_a_start_without_a_type_keeps_the_registered_one(client: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(client, vehicle_type="auv")

    async def shown_type() -> str:
        r = await client.get(f"/api/vehicles/{vid}", headers=ADMIN)
        assert r.status_code == 200, r.text
        return str(r.json()["vehicle_type"])

    for _ in range(2):  # a new instance, then the same one resumed
        r = await client.post("/upper/start_instance", headers=vh, json={"vehicle_id": vid})
        assert r.status_code == 200, r.text
        assert await shown_type() == "auv"
    r = await client.post(
        "/upper/start_instance", headers=vh, json={"vehicle_id": vid, "vehicle_type": "rov"}
    )
    assert r.status_code == 200 and await shown_type() == "rov"


@pytest.mark.parametrize(
    "name", ["\x1b[2J\x1b[31mHACKED", "a\x00b", "two\nlines", "c1\x9bx", "Alpha\u202eahplA"]
)
async def test_a_name_with_control_characters_is_422(client: httpx.AsyncClient, name: str) -> None:
    vid, vh = await make_vehicle(client)
    r = await client.post(
        "/upper/start_instance", headers=vh, json={"vehicle_id": vid, "name": name}
    )
    assert r.status_code == 422, r.text
    assert [d["field"] for d in r.json()["error"]["details"]] == ["name"]
    r = await client.post(
        "/api/vehicles", headers=ADMIN, json={"vehicle_id": "ctl-1", "name": name}
    )
    assert r.status_code == 422, r.text
    assert [d["field"] for d in r.json()["error"]["details"]] == ["name"]


async def test_a_new_instance_takes_up_the_name_type_and_position_the_last_one_had(
    client: httpx.AsyncClient,
) -> None:
    """After a finish, a start that gives no name or type keeps those its last start gave
    (not the registered ones), and the boat stays on the map at its latest sample."""
    vid, vh = await make_vehicle(client, vehicle_type="auv")
    first = await client.post(
        "/upper/start_instance",
        headers=vh,
        json={"vehicle_id": vid, "name": "Renamed", "vehicle_type": "usv"},
    )
    iid = first.json()["instance_id"]
    r = await client.post(
        "/upper/update_param",
        headers=vh,
        json={"instance_id": iid, "samples": [sample(1, lat=43.95, depth_m=1.5)]},
    )
    assert r.status_code == 200, r.text
    await client.post("/upper/finish_instance", headers=vh, json={"instance_id": iid})

    r = await client.post("/upper/start_instance", headers=vh, json={"vehicle_id": vid})
    assert r.status_code == 200 and r.json()["resumed"] is False
    view = (await client.get(f"/api/vehicles/{vid}", headers=ADMIN)).json()
    assert (view["name"], view["vehicle_type"]) == ("Renamed", "usv")
    assert view["position"]["seq"] == 1 and view["position"]["lat"] == 43.95
    got = await client.get(
        "/client/get_param", headers=ADMIN, params={"instance_id": r.json()["instance_id"]}
    )
    assert got.json()["position"]["depth_m"] == 1.5


async def test_a_start_without_capabilities_keeps_the_ones_the_vehicle_gave(
    client: httpx.AsyncClient,
) -> None:
    """A resume (then a new instance) that leaves ``capabilities`` out keeps those the last
    start gave, as it keeps the name and type; an explicit ``[]`` still means none."""
    vid, vh = await make_vehicle(client)
    caps = ["stop", "go_to", "keep_station", "follow_path"]
    first = await start_instance(client, vid, vh, capabilities=caps)

    async def shown(iid: str) -> list[str]:
        r = await client.post("/client/connect_instance", headers=ADMIN, json={"instance_id": iid})
        assert r.status_code == 200, r.text
        return list(r.json()["instance"]["capabilities"])

    r = await client.post("/upper/start_instance", headers=vh, json={"vehicle_id": vid})
    assert r.status_code == 200 and r.json()["resumed"] is True, r.text
    assert await shown(first["instance_id"]) == caps
    await client.post(
        "/upper/finish_instance", headers=vh, json={"instance_id": first["instance_id"]}
    )
    r = await client.post(
        "/upper/start_instance", headers=vh, json={"vehicle_id": vid, "capabilities": None}
    )
    assert r.status_code == 200 and r.json()["resumed"] is False, r.text
    fresh = r.json()["instance_id"]
    assert await shown(fresh) == caps
    r = await client.post(
        "/upper/start_instance", headers=vh, json={"vehicle_id": vid, "capabilities": []}
    )
    assert r.status_code == 200 and r.json()["resumed"] is True, r.text
    assert await shown(fresh) == []


async def test_a_presence_change_found_late_says_when_the_vehicle_was_last_heard(
    clocked_client: httpx.AsyncClient, clock: FakeClock
) -> None:
    """The server down for an hour finds its vehicles offline when it is back: the event is
    dated then, and says since when each was silent (it read as a one-second blip)."""
    client = clocked_client
    vid, vh = await make_vehicle(client)
    started = await start_instance(client, vid, vh)
    clock.advance(3600)

    async def told() -> list[dict[str, Any]]:
        params = {"vehicle_id": vid, "kind": "presence"}
        return list(
            (await client.get("/api/events", headers=ADMIN, params=params)).json()["events"]
        )

    async def offline_told() -> bool:
        return any(e["data"]["presence"] == "offline" for e in await told())

    await eventually(offline_told)
    [offline] = [e for e in await told() if e["data"]["presence"] == "offline"]
    assert offline["data"]["last_seen"] == started["server_time"]
    assert parse_ts(offline["at"]) > parse_ts(started["server_time"])
    await client.post("/upper/heartbeat", headers=vh, json={"instance_id": started["instance_id"]})

    async def online_told() -> bool:
        return any(e["data"]["presence"] == "online" for e in await told())

    await eventually(online_told)
    [online] = [e for e in await told() if e["data"]["presence"] == "online"]
    assert "last_seen" not in online["data"]
