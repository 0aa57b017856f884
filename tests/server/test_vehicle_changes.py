"""An admin puts a registered vehicle's name or type right: ``PATCH /api/vehicles/{id}``."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import httpx
import pytest

from server.settings import Settings
from tests.factories import ADMIN, make_user, make_vehicle, start_instance
from tests.live import call, connect, recv_until, serve

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


async def _patch(client: httpx.AsyncClient, vid: str, **body: Any) -> httpx.Response:
    return await client.patch(f"/api/vehicles/{vid}", headers=ADMIN, json=body)


async def _view(client: httpx.AsyncClient, vehicle_id: str) -> dict[str, Any]:
    r = await client.get(f"/api/vehicles/{vehicle_id}", headers=ADMIN)
    assert r.status_code == 200, r.text
    view: dict[str, Any] = r.json()
    return view


async def _bare_start(
    client: httpx.AsyncClient, vehicle_id: str, headers: dict[str, str]
) -> dict[str, Any]:
    """A start that announces no name and no type, as the fleet-agent's adapters send it."""
    r = await client.post("/upper/start_instance", headers=headers, json={"vehicle_id": vehicle_id})
    assert r.status_code == 200, r.text
    started: dict[str, Any] = r.json()
    return started


async def test_a_vehicle_registered_with_the_wrong_type_is_put_right_for_good(
    client: httpx.AsyncClient,
) -> None:
    vid, vehicle = await make_vehicle(client, vehicle_type="usv")  # it is an AUV
    first = await _bare_start(client, vid, vehicle)
    r = await _patch(client, vid, vehicle_type="auv", name="Deep One")
    assert r.status_code == 200, r.text
    assert r.json()["vehicle_type"] == "auv" and r.json()["name"] == "Deep One"
    view = await _view(client, vid)
    assert (view["name"], view["vehicle_type"]) == ("Deep One", "auv")
    assert view["instance_id"] == first["instance_id"]
    listed = (await client.get("/api/vehicles", headers=ADMIN)).json()["vehicles"]
    assert [(v["name"], v["vehicle_type"]) for v in listed if v["vehicle_id"] == vid] == [
        ("Deep One", "auv")
    ]

    # Its parameters change (the instance's record written whole) and it finishes; its
    # next instance goes on with the name and type put right.
    r = await client.post(
        "/upper/update_param",
        headers=vehicle,
        json={"instance_id": first["instance_id"], "params": {"mode": "survey"}},
    )
    assert r.status_code == 200, r.text
    assert (await _view(client, vid))["vehicle_type"] == "auv"
    r = await client.post(
        "/upper/finish_instance", headers=vehicle, json={"instance_id": first["instance_id"]}
    )
    assert r.status_code == 200, r.text
    second = await _bare_start(client, vid, vehicle)
    assert second["instance_id"] != first["instance_id"]
    view = await _view(client, vid)
    assert (view["name"], view["vehicle_type"]) == ("Deep One", "auv")


async def test_a_name_the_vehicle_announces_at_its_start_still_wins(
    client: httpx.AsyncClient,
) -> None:
    vid, vehicle = await make_vehicle(client)
    await start_instance(client, vid, vehicle, name="Alpha")
    assert (await _patch(client, vid, name="Bravo")).json()["name"] == "Bravo"
    await start_instance(client, vid, vehicle, name="Alpha")  # its agent says so again
    assert (await _view(client, vid))["name"] == "Alpha"


async def test_a_vehicle_that_never_started_is_changed_in_its_record(
    client: httpx.AsyncClient,
) -> None:
    vid, vehicle = await make_vehicle(client)
    r = await _patch(client, vid, vehicle_type="rov")
    assert r.status_code == 200, r.text
    assert r.json()["vehicle_type"] == "rov" and r.json()["presence"] == "offline"
    await _bare_start(client, vid, vehicle)
    assert (await _view(client, vid))["vehicle_type"] == "rov"


async def test_the_change_is_an_event_saying_what_was_there_before(
    client: httpx.AsyncClient,
) -> None:
    vid, vehicle = await make_vehicle(client)  # named vid.upper() by the factory
    iid = (await _bare_start(client, vid, vehicle))["instance_id"]
    await _patch(client, vid, name="Survey 1", vehicle_type="usv")  # the type as it was
    await _patch(client, vid, name="Survey 1")  # nothing to change: no event
    r = await client.get(
        "/api/events", headers=ADMIN, params={"vehicle_id": vid, "kind": "vehicle_changed"}
    )
    assert r.status_code == 200, r.text
    events = r.json()["events"]
    assert len(events) == 1, events
    assert events[0]["instance_id"] == iid and events[0]["actor"]
    assert events[0]["data"] == {"name": "Survey 1", "was": {"name": vid.upper()}}


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({"name": ""}, "name"),
        ({"vehicle_type": ""}, "vehicle_type"),
        ({"vehicle_type": "x" * 33}, "vehicle_type"),
        ({"name": 5}, "name"),
        ({"vehicle_id": "other"}, "vehicle_id"),
        ({"typ": "auv"}, "typ"),
    ],
)
async def test_a_bad_change_is_a_422_naming_the_field_and_changes_nothing(
    client: httpx.AsyncClient, body: dict[str, Any], field: str
) -> None:
    vid, _ = await make_vehicle(client, vehicle_type="usv")
    r = await _patch(client, vid, **body)
    assert r.status_code == 422, r.text
    assert field in r.text
    view = await _view(client, vid)
    assert (view["name"], view["vehicle_type"]) == (vid.upper(), "usv")


async def test_only_an_admin_changes_a_vehicle_and_only_one_that_exists(
    client: httpx.AsyncClient,
) -> None:
    vid, vehicle = await make_vehicle(client)
    _, manager = await make_user(client, "manager", [vid])
    for headers in (manager, vehicle):
        r = await client.patch(f"/api/vehicles/{vid}", headers=headers, json={"name": "X"})
        assert r.status_code == 403, r.text
        assert r.json()["error"]["code"]
    r = await client.patch(f"/api/vehicles/{vid}", json={"name": "X"})
    assert r.status_code == 401, r.text
    r = await _patch(client, "no-such-vehicle", name="X")
    assert r.status_code == 404, r.text
    assert r.json()["error"]["code"]
    assert (await _view(client, vid))["name"] == vid.upper()


async def test_operators_watching_the_fleet_see_the_new_name_at_once(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as api:
        vid, _ = await make_vehicle(api)
        other, _ = await make_vehicle(api)
        _, operator = await make_user(api, "operator", [vid])
        async with await connect(base, "/ws/client", operator["Authorization"][7:]) as ws:
            await call(ws, "subscribe", "s", topics=["fleet"])
            snapshot = await recv_until(ws, lambda f: f.get("snapshot") is True)
            assert [v["name"] for v in snapshot["data"]["vehicles"]] == [vid.upper()]
            assert (await _patch(api, other, name="Not Yours")).status_code == 200
            assert (await _patch(api, vid, name="Renamed")).status_code == 200
            frame = await recv_until(
                ws, lambda f: f.get("op") == "event" and f.get("topic") == "fleet"
            )
            assert frame["data"]["vehicles"] == [{"vehicle_id": vid, "name": "Renamed"}]
