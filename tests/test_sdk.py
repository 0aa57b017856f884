"""The operator SDK (remote_client.sdk) on the app in process and on a server: missions,
control, names, administration, parameters, tracks, the event log, the local copy (its
live events: test_sdk_events.py)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import httpx
import pytest

from remote_client.localcopy import LocalCopy, sync_vehicle
from remote_client.sdk import (
    AmbiguousName,
    FleetApiError,
    FleetClient,
    TrackPage,
    UnknownVehicle,
)
from tests.factories import (
    ADMIN_TOKEN,
    bearer,
    make_user,
    make_vehicle,
    sample,
    start_instance,
    unique,
)

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


def _token(headers: dict[str, str]) -> str:
    return headers["Authorization"].removeprefix("Bearer ")


async def test_missions_and_control_through_the_sdk(client: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    _, op = await make_user(client, "operator", vehicles=[vid], username="ines")
    admin = FleetClient("http://test", ADMIN_TOKEN, client=client)
    ines = FleetClient("http://test", _token(op), client=client)

    assert [v["vehicle_id"] for v in (await ines.vehicles())["vehicles"]] == [vid]
    with pytest.raises(FleetApiError) as refused:
        await ines.go_to(iid, 43.95, 15.45)
    assert refused.value.status == 409 and refused.value.code == "control_not_held"
    assert refused.value.details[0]["instance_id"] == iid

    request = await ines.request_control(iid)
    pending = (await admin.control_requests(iid))["requests"]
    assert [r["request_id"] for r in pending] == [request["request_id"]]
    assert (await admin.grant_control(iid, "ines", 600))["holder"] == "ines"

    with pytest.raises(FleetApiError) as not_a_number:  # JSON cannot carry it: not sent
        await ines.go_to(iid, float("nan"), -15.4)
    assert (not_a_number.value.status, not_a_number.value.code) == (422, "invalid")
    went = (await ines.go_to(iid, -33.9, -15.4, speed_mps=2.0))["commands"][0]
    held = (await ines.keep_station([iid], radius_m=4.0))["commands"][0]
    path = await ines.follow_path(iid, [(43.941, 15.441), (43.942, 15.442)], speed_mps=1.0)
    listed = {c["command_id"]: c for c in (await ines.commands(iid))["commands"]}
    assert listed[went["command_id"]]["args"] == {"lat": -33.9, "lon": -15.4, "speed_mps": 2.0}
    assert listed[held["command_id"]]["args"] == {"radius_m": 4.0}  # no position: where it is
    path_id = path["commands"][0]["command_id"]
    assert listed[path_id]["args"]["waypoints"][0] == {"lat": 43.941, "lon": 15.441}
    assert (await ines.cancel(path_id))["status"] == "cancelled"

    assert await ines.release_control(iid) == {"ok": True}
    with pytest.raises(FleetApiError) as after:
        await ines.keep_station([iid])
    assert after.value.code == "control_not_held"
    stopped = await ines.stop()  # stop needs no lease; no instance: every vehicle
    assert [c["instance_id"] for c in stopped["commands"]] == [iid]
    with pytest.raises(ValueError, match="no instance given"):
        await ines.stop([])  # a filter that matched nothing stops nothing
    twice = await ines.stop([iid, iid])  # by its id and by its name: one stop, not a 422
    assert [c["instance_id"] for c in twice["commands"]] == [iid]
    with pytest.raises(FleetApiError) as not_manager:
        await ines.revoke_control(iid)
    assert not_manager.value.status == 403


async def test_a_user_logs_in_with_a_password_and_out(client: httpx.AsyncClient) -> None:
    """``FleetClient.login``: a session as the user (its rights), ``expires_in`` said; a
    wrong password is a 401 ``FleetApiError``; ``logout`` ends the session at once."""
    admin = FleetClient("http://test", ADMIN_TOKEN, client=client)
    name = unique("cy")
    await admin.create_user(name, "viewer", password="long-enough-1")
    with pytest.raises(FleetApiError) as wrong:
        await FleetClient.login("http://test", name, "not-it-at-all", client=client)
    assert wrong.value.status == 401

    fleet = await FleetClient.login("http://test", name, "long-enough-1", client=client)
    assert fleet.expires_in == 12 * 3600
    assert (await fleet.vehicles())["vehicles"] == []  # a viewer of no vehicle
    with pytest.raises(FleetApiError) as not_admin:
        await fleet.users()
    assert not_admin.value.status == 403
    assert await fleet.logout() is True
    with pytest.raises(FleetApiError) as ended:
        await fleet.vehicles()
    assert ended.value.status == 401
    assert await admin.logout() is False  # an API token outlives it


async def test_telemetry_pages_cover_every_sample_once(client: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    body = {"instance_id": iid, "samples": [sample(seq) for seq in range(1, 24)]}
    assert (await client.post("/upper/update_param", headers=vh, json=body)).is_success
    fleet = FleetClient("http://test", ADMIN_TOKEN, client=client)
    pages = [page async for page in fleet.telemetry_pages(vid, page=10)]
    assert [len(p) for p in pages] == [10, 10, 3]
    assert [s["seq"] for p in pages for s in p] == list(range(1, 24))
    with pytest.raises(FleetApiError) as unknown:
        _ = [page async for page in fleet.telemetry_pages("no-such-vehicle")]
    assert unknown.value.status == 404


async def _start(
    client: httpx.AsyncClient, vid: str, vh: dict[str, str], name: str
) -> dict[str, Any]:
    """An instance that announces ``name`` as the vehicle's display name."""
    capabilities = ["stop", "go_to", "keep_station", "follow_path"]
    body = {"vehicle_id": vid, "name": name, "vehicle_type": "usv", "capabilities": capabilities}
    r = await client.post("/upper/start_instance", headers=vh, json=body)
    assert r.status_code == 200, r.text
    answer: dict[str, Any] = r.json()
    return answer


async def test_a_vehicle_name_stands_for_the_vehicle_and_its_instance(
    client: httpx.AsyncClient,
) -> None:
    alpha, ah = await make_vehicle(client)
    bravo, bh = await make_vehicle(client)
    twin, th = await make_vehicle(client)
    idle, _ = await make_vehicle(client)
    first = (await _start(client, alpha, ah, "Alpha One"))["instance_id"]
    r = await client.post("/upper/finish_instance", headers=ah, json={"instance_id": first})
    assert r.status_code == 200
    iid = (await _start(client, alpha, ah, "Alpha One"))["instance_id"]
    await _start(client, bravo, bh, "Bravo")
    await _start(client, twin, th, "bravo")
    fleet = FleetClient("http://test", ADMIN_TOKEN, client=client)

    assert await fleet.vehicle_id_of(alpha) == alpha
    assert await fleet.vehicle_id_of("Alpha One") == alpha
    assert await fleet.vehicle_id_of("alpha one") == alpha  # any case, when one matches
    assert await fleet.vehicle_id_of("Bravo") == bravo  # the exact name first
    assert await fleet.instance_ids_of([alpha, "Alpha One", iid]) == [iid, iid, iid]
    assert await fleet.instance_id_of(first) == first  # an older instance: the server knows it
    instance = await fleet.instance_of("alpha one")  # which vehicle an instance is
    assert (instance["instance_id"], instance["vehicle_id"], instance["name"]) == (
        iid, alpha, "Alpha One"
    )  # fmt: skip
    views = await fleet.instance_vehicles([iid, first])  # the older one as connect shows it
    assert {i: (v["vehicle_id"], v["name"]) for i, v in views.items()} == {
        iid: (alpha, "Alpha One"), first: (alpha, "Alpha One")
    }  # fmt: skip
    with pytest.raises(AmbiguousName) as two:
        await fleet.instance_id_of("BRAVO")
    assert two.value.code == "ambiguous_name" and bravo in two.value.message
    with pytest.raises(UnknownVehicle) as unknown:
        await fleet.instance_id_of("Zulu")
    assert unknown.value.status == 404 and "'Zulu'" in unknown.value.message
    with pytest.raises(UnknownVehicle) as never_started:
        await fleet.instance_id_of(idle)
    assert "has not started an instance" in never_started.value.message
    with pytest.raises(UnknownVehicle):
        await fleet.vehicle_id_of("Zulu")

    # What a caller may not see, it cannot name either.
    _, op = await make_user(client, "operator", vehicles=[bravo])
    blind = FleetClient("http://test", _token(op), client=client)
    with pytest.raises(UnknownVehicle):
        await blind.instance_id_of("Alpha One")
    with pytest.raises(UnknownVehicle):
        await blind.instance_id_of(iid)
    assert await blind.vehicle_id_of("bravo") == bravo  # one match among those it sees


async def test_admin_registers_vehicles_gateways_and_users_and_their_tokens(
    client: httpx.AsyncClient,
) -> None:
    admin = FleetClient("http://test", ADMIN_TOKEN, client=client)
    made = await admin.create_vehicle("sdk-usv", "Echo", "auv")
    assert made["vehicle_id"] == "sdk-usv" and made["token"]
    view = await admin.vehicle("sdk-usv")
    assert (view["name"], view["vehicle_type"], view["presence"]) == ("Echo", "auv", "offline")
    start = {"vehicle_id": "sdk-usv", "name": "", "vehicle_type": "auv", "capabilities": []}

    async def starts(token: str) -> int:
        r = await client.post("/upper/start_instance", headers=bearer(token), json=start)
        return r.status_code

    assert await starts(made["token"]) == 200
    rotated = await admin.rotate_token("vehicle", "sdk-usv")
    assert await starts(made["token"]) == 401 and await starts(rotated["token"]) == 200
    assert await admin.revoke_tokens("vehicle", "sdk-usv") == {"ok": True}
    assert await starts(rotated["token"]) == 401

    gateway = await admin.create_gateway("sdk-gw", ["sdk-usv"])
    assert gateway["vehicles"] == ["sdk-usv"] and await starts(gateway["token"]) == 200
    again = await admin.rotate_token("gateway", "sdk-gw")
    assert await starts(gateway["token"]) == 401 and await starts(again["token"]) == 200
    listed = (await admin.gateways())["gateways"]
    assert [(g["gateway_id"], g["vehicles"], g["active_tokens"]) for g in listed] == [
        ("sdk-gw", ["sdk-usv"], 1)
    ]
    assert await admin.revoke_tokens("gateway", "sdk-gw") == {"ok": True}
    assert (await admin.gateways())["gateways"][0]["active_tokens"] == 0
    assert await starts(again["token"]) == 401

    user = await admin.create_user("sdk-ana", "operator", ["sdk-usv"])
    ana = FleetClient("http://test", user["token"], client=client)
    assert [v["vehicle_id"] for v in (await ana.vehicles())["vehicles"]] == ["sdk-usv"]
    listed = {u["username"]: u for u in (await admin.users())["users"]}
    assert listed["sdk-ana"]["role"] == "operator" and listed["sdk-ana"]["disabled"] is False
    changed = await admin.update_user("sdk-ana", role="viewer", vehicles=[])
    assert (changed["role"], changed["vehicles"]) == ("viewer", [])
    assert (await admin.update_user("sdk-ana", disabled=True))["disabled"] is True
    with pytest.raises(FleetApiError) as disabled:
        await ana.vehicles()
    assert disabled.value.status == 401
    await admin.update_user("sdk-ana", disabled=False)
    assert (await ana.vehicles())["vehicles"] == []  # the API token works again
    fresh = await admin.rotate_token("user", "sdk-ana")
    with pytest.raises(FleetApiError):
        await ana.vehicles()
    ana = FleetClient("http://test", fresh["token"], client=client)
    assert await ana.vehicles() == {"vehicles": []}
    assert await admin.revoke_tokens("user", "sdk-ana") == {"ok": True}
    with pytest.raises(FleetApiError) as revoked:
        await ana.vehicles()
    assert revoked.value.status == 401

    with pytest.raises(FleetApiError) as taken:
        await admin.create_vehicle("sdk-usv")
    assert taken.value.status == 409
    with pytest.raises(FleetApiError) as not_admin:
        await FleetClient("http://test", user["token"], client=client).users()
    assert not_admin.value.status == 401  # revoked above
    _, viewer = await make_user(client, "viewer")
    with pytest.raises(FleetApiError) as forbidden:
        await FleetClient("http://test", _token(viewer), client=client).create_user("x", "admin")
    assert forbidden.value.status == 403
    with pytest.raises(ValueError, match="vehicle, gateway or user"):
        await admin.rotate_token("boat", "sdk-usv")


async def test_params_track_pages_events_and_a_command(client: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(client)
    params = {"mode": "survey", "gain": 0.5, "sonar": {"range_m": 40}}
    iid = (await start_instance(client, vid, vh, params=params))["instance_id"]
    start = datetime(2026, 11, 22, 10, 0, 0, tzinfo=UTC)
    seqs = range(1, 10_502)  # past one page of a track (10,000 points)
    for chunk in (seqs[:5000], seqs[5000:10_000], seqs[10_000:]):
        body = {"instance_id": iid, "samples": [sample(s, start + timedelta(seconds=s))
                                                for s in chunk]}  # fmt: skip
        assert (await client.post("/upper/update_param", headers=vh, json=body)).is_success
    fleet = FleetClient("http://test", ADMIN_TOKEN, client=client)

    got = await fleet.params(iid, ["mode", "sonar"])
    assert got["params"] == {"mode": "survey", "sonar": {"range_m": 40}}
    assert got["position"]["seq"] == 10_501
    assert (await fleet.params(iid))["params"] == params

    since, until = "2026-11-22T10:00:00.000Z", "2026-11-22T13:00:00.000Z"
    pages = [p async for p in fleet.track_pages(vid, since=since, until=until)]
    assert len(pages) == 2 and pages[0].next_from and pages[1].next_from is None
    points = [pt for p in pages for pt in _points(p)]
    assert [pt["seq"] for pt in points] == list(seqs)  # none lost or twice at the cut
    texts = [p async for p in fleet.track_pages(vid, since=since, until=until, fmt="csv")]
    assert len(texts) == 2 and str(texts[0].content).startswith("ts,seq,lat,lon")
    assert texts[0].next_from == pages[0].next_from  # the same cut, told in a header
    few = [p async for p in fleet.track_pages(vid, since=since, until=until, max_points=50)]
    assert len(few) == 1 and len(_points(few[0])) == 50
    with pytest.raises(FleetApiError) as unknown:
        _ = [p async for p in fleet.track_pages("no-such", since=since, until=until)]
    assert unknown.value.status == 404

    queued = (await fleet.stop([iid]))["commands"][0]
    command = await fleet.command(queued["command_id"])
    assert command["type"] == "stop" and command["instance_id"] == iid
    log = (await fleet.event_log(vehicle_id=vid, kind="command"))["events"]
    assert [e["data"]["command_id"] for e in log] == [queued["command_id"]]
    assert (await fleet.event_log(vehicle_id=vid, since="2100-01-01T00:00:00Z"))["events"] == []
    connected = (await fleet.connect(vehicle_id=vid))["instance"]
    assert connected["instance_id"] == iid and connected["presence"] == "online"


def _points(page: TrackPage) -> list[dict[str, Any]]:
    assert isinstance(page.content, dict)
    points: list[dict[str, Any]] = page.content["points"]
    return points


async def test_sync_keeps_a_local_copy_and_fetches_only_what_is_new(
    client: httpx.AsyncClient, tmp_path: Path
) -> None:
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]

    async def ingest(seqs: range) -> None:
        samples = [sample(s, battery_pct=50.0) for s in seqs]
        samples[0]["data"] = {"sonar": [1, 2]}
        body = {"instance_id": iid, "samples": samples}
        assert (await client.post("/upper/update_param", headers=vh, json=body)).is_success

    await ingest(range(1, 26))
    asked: list[httpx.URL] = []

    async def note(request: httpx.Request) -> None:
        if request.url.path.endswith("/telemetry"):
            asked.append(request.url)

    client.event_hooks["request"].append(note)
    fleet = FleetClient("http://test", ADMIN_TOKEN, client=client)
    vehicle = (await fleet.resolve_vehicles([vid]))[0]
    with LocalCopy(tmp_path / "fleet.sqlite") as copy:
        first = await sync_vehicle(fleet, copy, vehicle, page=10)
        assert (first.added, first.total, first.through_seq) == (25, 25, 25)
        assert [u.params["after_seq"] for u in asked] == ["0", "10", "20"]

        await ingest(range(26, 31))
        asked.clear()
        second = await sync_vehicle(fleet, copy, vehicle, page=10)
        assert (second.added, second.total, second.through_seq) == (5, 30, 30)
        assert [u.params["after_seq"] for u in asked] == ["25"]  # only what is new

        stored = copy.samples(vid)
        assert [s["seq"] for s in stored] == list(range(1, 31))  # each once
        assert stored[0]["data"] == {"sonar": [1, 2]} and stored[25]["data"] == {"sonar": [1, 2]}
        assert stored[3]["battery_pct"] == 50.0 and stored[3]["ts"] == "2026-11-22T10:00:04.000Z"

        full = await sync_vehicle(fleet, copy, vehicle, full=True)
        assert (full.added, full.total) == (0, 30)  # read again, nothing stored twice

    # Interrupted half-way: the pages stored stay, the next sync goes on after them.
    await ingest(range(31, 61))
    calls = 0

    async def cut_after_two_pages(request: httpx.Request) -> None:
        nonlocal calls
        if request.url.path.endswith("/telemetry"):
            calls += 1
            if calls == 3:
                raise httpx.ReadError("link lost", request=request)

    client.event_hooks["request"].append(cut_after_two_pages)
    with LocalCopy(tmp_path / "fleet.sqlite") as copy:
        with pytest.raises(httpx.ReadError):
            await sync_vehicle(fleet, copy, vehicle, page=10)
        assert copy.high_seq(vid) == 50 and copy.count(vid) == 50
        asked.clear()
        resumed = await sync_vehicle(fleet, copy, vehicle, page=10)
        assert (resumed.added, resumed.total, resumed.through_seq) == (10, 60, 60)
        assert asked[0].params["after_seq"] == "50"
