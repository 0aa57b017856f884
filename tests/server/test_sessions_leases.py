"""Sessions and roles (issue 12, finding 12): a new password ends the user's other
sessions; a user who may no longer hold a lease (demoted, the vehicle taken away,
disabled) loses it, with everything a lease's end brings."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from typing import Any

import httpx
import pytest

from server.settings import Settings
from tests.factories import ADMIN, bearer, make_user, make_vehicle
from tests.live import call, connect, http, recv_until
from tests.server.commanding import GO_TO, World, world

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")

PASSWORD = "correct horse battery"
NEW_PASSWORD = "tr0ub4dor and 3"


async def login(c: httpx.AsyncClient, username: str, password: str) -> dict[str, str]:
    r = await c.post("/auth/token", json={"username": username, "password": password})
    assert r.status_code == 200, r.text
    return bearer(r.json()["access_token"])


async def status(c: httpx.AsyncClient, headers: dict[str, str]) -> int:
    return (await c.get("/api/vehicles", headers=headers)).status_code


# ---- (a) sessions ------------------------------------------------------------------------


async def test_a_new_password_ends_the_users_sessions_and_keeps_the_api_token(
    client: httpx.AsyncClient,
) -> None:
    name, api_token = await make_user(client, "operator", password=PASSWORD)
    first, second = await login(client, name, PASSWORD), await login(client, name, PASSWORD)
    assert await status(client, first) == await status(client, second) == 200
    r = await client.patch(f"/api/users/{name}", headers=ADMIN, json={"password": NEW_PASSWORD})
    assert r.status_code == 200, r.text
    assert await status(client, first) == 401
    assert await status(client, second) == 401
    assert await status(client, api_token) == 200  # an API token is no session: it stays
    wrong = await client.post("/auth/token", json={"username": name, "password": PASSWORD})
    assert wrong.status_code == 401
    assert await status(client, await login(client, name, NEW_PASSWORD)) == 200


async def test_an_admin_changing_its_own_password_keeps_the_session_it_used(
    client: httpx.AsyncClient,
) -> None:
    name, _ = await make_user(client, "admin", password=PASSWORD)
    used, other = await login(client, name, PASSWORD), await login(client, name, PASSWORD)
    r = await client.patch(f"/api/users/{name}", headers=used, json={"password": NEW_PASSWORD})
    assert r.status_code == 200, r.text
    assert await status(client, used) == 200
    assert await status(client, other) == 401


async def test_disabling_ends_sessions_for_good(client: httpx.AsyncClient) -> None:
    name, api_token = await make_user(client, "viewer", password=PASSWORD)
    session = await login(client, name, PASSWORD)
    await client.patch(f"/api/users/{name}", headers=ADMIN, json={"disabled": True})
    assert await status(client, session) == await status(client, api_token) == 401
    await client.patch(f"/api/users/{name}", headers=ADMIN, json={"disabled": False})
    assert await status(client, session) == 401  # not brought back by enabling
    assert await status(client, api_token) == 200


async def test_other_changes_leave_sessions_alone(client: httpx.AsyncClient) -> None:
    vid, _ = await make_vehicle(client)
    name, _ = await make_user(client, "viewer", password=PASSWORD)
    session = await login(client, name, PASSWORD)
    r = await client.patch(f"/api/users/{name}", headers=ADMIN, json={"vehicles": [vid]})
    assert r.status_code == 200
    assert await status(client, session) == 200


# ---- (b) leases --------------------------------------------------------------------------


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    async with world(make_settings()) as w:
        yield w


async def control_of(w: World, instance_id: str) -> Any:
    r = await w.http.post(
        "/client/connect_instance", headers=ADMIN, json={"instance_id": instance_id}
    )
    assert r.status_code == 200, r.text
    return r.json()["instance"]["control"]


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        ({"role": "viewer"}, "holder_demoted"),
        ({"vehicles": "other"}, "holder_lost_vehicle"),
        ({"disabled": True}, "holder_disabled"),
    ],
)
async def test_a_holder_who_may_no_longer_hold_loses_the_lease(
    w: World, change: dict[str, Any], reason: str
) -> None:
    v = await w.vehicle()
    other = await w.vehicle()
    op = await w.operator_in_control(v)
    go = await w.queued(op, v, GO_TO, ttl_s=600)
    w.clock.advance(0.000123)  # extended at a time the store keeps to the millisecond only
    assert (await w.grant(v, op.username)).status_code == 200
    view = await w.http.get(f"/api/vehicles/{v.vehicle_id}", headers=ADMIN)
    assert view.json()["control"]["holder"] == op.username
    if change.get("vehicles") == "other":
        change = {"vehicles": [other.vehicle_id]}
    r = await w.http.patch(f"/api/users/{op.username}", headers=ADMIN, json=change)
    assert r.status_code == 200, r.text

    assert await control_of(w, v.instance_id) is None
    view = await w.http.get(f"/api/vehicles/{v.vehicle_id}", headers=ADMIN)
    assert view.json()["control"] is None  # the fleet view agrees at once
    cmd = await w.command(go)
    assert cmd["status"] == "cancelled"
    assert cmd["history"][-1]["detail"] == "lease_ended"
    events = (
        await w.http.get("/api/events", headers=ADMIN, params={"vehicle_id": v.vehicle_id})
    ).json()["events"]
    revoke = [e for e in events if e["kind"] == "control_revoke"]
    assert len(revoke) == 1
    assert revoke[0]["data"]["holder"] == op.username
    assert revoke[0]["data"]["reason"] == reason
    assert revoke[0]["actor"] == "admin"
    # And no way back in on the old lease: a grant now is refused for the same reason.
    assert (await w.grant(v, op.username)).status_code == 422


@pytest.mark.parametrize("change", [{"role": "manager"}, {"vehicles": "both"}])
async def test_a_holder_who_may_still_hold_keeps_the_lease(
    w: World, change: dict[str, Any]
) -> None:
    v = await w.vehicle()
    other = await w.vehicle()
    op = await w.operator_in_control(v)
    go = await w.queued(op, v, GO_TO, ttl_s=600)
    if change.get("vehicles") == "both":
        change = {"vehicles": [v.vehicle_id, other.vehicle_id]}
    r = await w.http.patch(f"/api/users/{op.username}", headers=ADMIN, json=change)
    assert r.status_code == 200, r.text
    assert (await control_of(w, v.instance_id))["holder"] == op.username
    assert (await w.command(go))["status"] == "queued"


async def test_a_demoted_users_pending_request_is_dropped(w: World) -> None:
    v = await w.vehicle()
    op = await w.person("operator", v)
    r = await w.http.post(
        "/client/request_control", headers=op.headers, json={"instance_id": v.instance_id}
    )
    assert r.status_code == 200
    await w.http.patch(f"/api/users/{op.username}", headers=ADMIN, json={"role": "viewer"})
    r = await w.http.get("/client/control_requests", headers=ADMIN)
    assert r.json()["requests"] == []


async def test_the_vehicle_socket_is_told_when_a_demoted_holder_loses_control(
    base: str, api: httpx.AsyncClient
) -> None:
    vid, vh = await make_vehicle(api)
    op, op_headers = await make_user(api, "operator", [vid])
    token = vh["Authorization"].removeprefix("Bearer ")
    async with await connect(base, "/ws/vehicle", token) as ws:
        ack = await call(ws, "start_instance", "s1", vehicle_id=vid, capabilities=["go_to"])
        iid = ack["instance_id"]
        r = await api.post(
            "/client/grant_control",
            headers=ADMIN,
            json={"instance_id": iid, "user": op, "duration_s": 600},
        )
        assert r.status_code == 200, r.text
        held = await recv_until(ws, lambda f: f["op"] == "control" and f["control"] is not None)
        assert held["control"]["holder"] == op
        async with http(base, op_headers["Authorization"].removeprefix("Bearer ")) as mine:
            r = await mine.post(
                "/client/submit_control",
                json={"instance_ids": [iid], "command": GO_TO, "ttl_s": 600},
            )
        assert r.status_code == 202, r.text
        command_id = r.json()["commands"][0]["command_id"]
        pushed = await recv_until(ws, lambda f: f["op"] == "command")
        assert pushed["command_id"] == command_id

        r = await api.patch(f"/api/users/{op}", headers=ADMIN, json={"role": "viewer"})
        assert r.status_code == 200
        gone = await recv_until(ws, lambda f: f["op"] == "control")
        assert gone == {"op": "control", "instance_id": iid, "control": None}
        cmd = (await api.get(f"/api/commands/{command_id}", headers=ADMIN)).json()
        assert cmd["status"] == "cancelled"
        assert cmd["history"][-1]["detail"] == "lease_ended"
