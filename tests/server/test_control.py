"""Arbitration through HTTP: grant, extend, hand over, revoke, release, expiry (the
requests for control: test_control_requests.py)."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from datetime import timedelta

import pytest

from fleet_protocol import parse_ts
from server.settings import Settings
from tests.factories import ADMIN
from tests.server.commanding import GO_TO, STOP, World, eventually, world

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    async with world(make_settings()) as w:
        yield w


async def test_grant_refusals(w: World) -> None:
    v = await w.vehicle()
    op = await w.person("operator", v)
    viewer = await w.person("viewer", v)
    outsider = await w.person("operator")
    other_boss = await w.person("manager")
    good = {"instance_id": v.instance_id, "user": op.username, "duration_s": 60}
    cases = [
        ({}, good, 401, "unauthorized"),
        (op.headers, good, 403, "forbidden"),
        (other_boss.headers, good, 404, "not_found"),  # not its vehicle: as if none
        (ADMIN, {**good, "user": viewer.username}, 422, "invalid"),
        (ADMIN, {**good, "user": outsider.username}, 422, "invalid"),
        (ADMIN, {**good, "user": "nobody"}, 422, "invalid"),
        (ADMIN, {**good, "duration_s": 0}, 422, "invalid"),
        (ADMIN, {**good, "duration_s": 86401}, 422, "invalid"),
        (ADMIN, {**good, "instance_id": "i-nope"}, 404, "not_found"),
    ]
    for headers, body, status, code in cases:
        r = await w.http.post("/client/grant_control", headers=headers, json=body)
        assert (r.status_code, r.json()["error"]["code"]) == (status, code), (body, r.text)
    r = await w.http.post(
        "/client/grant_control", headers=ADMIN, json={**good, "user": viewer.username}
    )
    assert r.json()["error"]["details"][0]["field"] == "user"


async def test_granting_again_to_the_holder_extends(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v, duration_s=60)
    w.clock.advance(50)
    r = await w.grant(v, op.username, duration_s=60)
    assert parse_ts(r.json()["expires_at"]) == w.clock.now + timedelta(seconds=60)
    w.clock.advance(30)  # past the first expiry, within the extension
    assert (await w.submit(op, [v], GO_TO)).status_code == 202


async def test_a_grant_to_someone_else_ends_the_lease_and_cancels_its_queue(w: World) -> None:
    v = await w.vehicle()
    first = await w.operator_in_control(v)
    go = await w.queued(first, v, GO_TO)
    second = await w.person("operator", v)
    assert (await w.grant(v, second.username)).status_code == 200
    cmd = await w.command(go)
    assert cmd["status"] == "cancelled"
    assert cmd["history"][-1]["detail"] == "lease_ended"
    assert (await w.submit(first, [v], GO_TO)).json()["error"]["code"] == "control_not_held"
    assert (await w.submit(second, [v], GO_TO)).status_code == 202


async def test_leases_changed_in_a_row_queue_one_hold(w: World) -> None:
    """Granted to one, another, a third, then revoked: each end of a lease queued a
    hold of its own (three keep_station, args {} where an operator's have a radius). The
    newest replaces the ones never handed out: the vehicle gets one, as an operator's."""
    v = await w.vehicle()
    boss = await w.person("manager", v)
    for who in ("operator", "operator", "manager"):
        person = await w.person(who, v)
        assert (await w.grant(v, person.username)).status_code == 200
        w.clock.advance(1)
    r = await w.client_post("revoke_control", boss.headers, instance_id=v.instance_id)
    assert r.status_code == 200, r.text
    [hold] = await w.poll(v)
    assert hold["type"] == "keep_station" and hold["issued_by"] == "system"
    assert hold["args"] == {"radius_m": 2.0}
    listed = await w.http.get(
        "/client/get_fbmessage", headers=boss.headers, params={"instance_id": v.instance_id}
    )
    holds = [c for c in listed.json()["commands"] if c["type"] == "keep_station"]
    replaced = [c for c in holds if c["command_id"] != hold["command_id"]]
    assert len(replaced) == 2 and all(c["status"] == "cancelled" for c in replaced), holds
    newer = {c["command_id"] for c in holds}  # each by the next: the last by the one held
    assert all(
        c["history"][-1]["detail"].removeprefix("superseded_by keep_station ") in newer
        for c in replaced
    ), replaced


async def test_revoke_ends_the_lease_cancels_motion_and_keeps_stops(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    boss = await w.person("manager", v)
    r = await w.submit(op, [v], GO_TO)
    go = r.json()["commands"][0]["command_id"]
    w.clock.advance(1)
    stop = await w.queued(op, v, STOP)  # supersedes ``go``
    w.clock.advance(1)
    later_go = await w.queued(op, v, GO_TO)
    r = await w.client_post("revoke_control", boss.headers, instance_id=v.instance_id)
    assert r.status_code == 200, r.text
    assert r.json() == {"ok": True, "revoked": True}
    assert (await w.command(later_go))["history"][-1]["detail"] == "lease_ended"
    assert (await w.command(stop))["status"] == "queued"
    assert (await w.command(go))["history"][-1]["detail"] == "superseded_by_stop"
    assert (await w.submit(op, [v], GO_TO)).json()["error"]["code"] == "control_not_held"
    # the stop under way holds the vehicle: no hold is sent to replace it there
    assert [c["command_id"] for c in await w.poll(v)] == [stop]
    events = await w.http.get(
        "/api/events", headers=ADMIN, params={"vehicle_id": v.vehicle_id, "kind": "hold_station"}
    )
    [said] = events.json()["events"]
    assert (said["data"]["command_id"], said["data"]["type"]) == (stop, "stop")
    assert said["data"]["stop_kept"] is True


async def test_revoke_refusals(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    other_boss = await w.person("manager")
    # the operator sees the vehicle but may not revoke (403); the other manager does not see it
    for headers, status in (({}, 401), (op.headers, 403), (other_boss.headers, 404)):
        r = await w.client_post("revoke_control", headers, instance_id=v.instance_id)
        assert r.status_code == status, r.text
    assert (await w.submit(op, [v], GO_TO)).status_code == 202  # still held


async def test_the_holder_releases(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    go = await w.queued(op, v, GO_TO)
    other = await w.person("operator", v)
    r = await w.client_post("release_control", other.headers, instance_id=v.instance_id)
    assert (r.status_code, r.json()["error"]["code"]) == (409, "control_not_held")
    r = await w.client_post("release_control", op.headers, instance_id=v.instance_id)
    assert r.status_code == 200, r.text
    assert (await w.command(go))["status"] == "cancelled"
    r = await w.client_post("release_control", op.headers, instance_id=v.instance_id)
    assert r.status_code == 409


async def test_a_lease_ends_at_its_expiry(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v, duration_s=60)
    go = await w.queued(op, v, GO_TO, ttl_s=600)
    w.clock.advance(60)
    assert (await w.submit(op, [v], GO_TO)).json()["error"]["code"] == "control_not_held"

    async def cancelled() -> bool:
        return (await w.command(go))["status"] == "cancelled"

    await eventually(cancelled)  # the lease sweeper, on its own beat
    assert (await w.command(go))["history"][-1]["detail"] == "lease_ended"


async def test_the_vehicle_and_the_operators_are_told_who_holds_control(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    r = await w.http.post(
        "/upper/start_instance",
        headers=v.headers,
        json={"vehicle_id": v.vehicle_id, "capabilities": ["go_to"]},
    )
    assert r.json()["resumed"] is True
    assert r.json()["control"]["holder"] == op.username
    r = await w.http.post(
        "/client/connect_instance", headers=op.headers, json={"instance_id": v.instance_id}
    )
    assert r.json()["instance"]["control"]["holder"] == op.username
    # A vehicle that polls over HTTP hears of it too (an extension), and of its end.
    assert (await w.poll_answer(v))["control"]["holder"] == op.username
    r = await w.client_post("revoke_control", ADMIN, instance_id=v.instance_id)
    assert r.status_code == 200, r.text
    assert (await w.poll_answer(v))["control"] is None


async def test_finish_instance_ends_the_lease(w: World) -> None:
    v = await w.vehicle()
    await w.operator_in_control(v)
    await w.http.post(
        "/upper/finish_instance", headers=v.headers, json={"instance_id": v.instance_id}
    )
    r = await w.http.post(
        "/client/connect_instance", headers=ADMIN, json={"instance_id": v.instance_id}
    )
    assert r.json()["instance"]["control"] is None
    r = await w.grant(v, (await w.person("operator", v)).username)
    assert r.json()["error"]["code"] == "instance_finished"


async def test_grants_revokes_and_releases_are_audited(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    await w.client_post("release_control", op.headers, instance_id=v.instance_id)
    await w.grant(v, op.username)
    await w.client_post("revoke_control", ADMIN, instance_id=v.instance_id)
    again = await w.client_post(
        "revoke_control", ADMIN, instance_id=v.instance_id
    )  # nobody holds it
    assert again.json() == {"ok": True, "revoked": False}  # no error, and nothing recorded
    r = await w.http.get("/api/events", headers=ADMIN, params={"vehicle_id": v.vehicle_id})
    kinds = [e["kind"] for e in r.json()["events"] if e["kind"].startswith("control_")]
    assert kinds == ["control_grant", "control_release", "control_grant", "control_revoke"]


async def test_a_grant_after_expiry_still_cancels_the_former_queue(w: World) -> None:
    v = await w.vehicle()
    first = await w.operator_in_control(v, duration_s=60)
    go = await w.queued(first, v, GO_TO, ttl_s=600)
    w.clock.advance(61)
    second = await w.person("operator", v)
    assert (await w.grant(v, second.username)).status_code == 200
    cmd = await w.command(go)
    assert cmd["status"] == "cancelled"
    assert cmd["history"][-1]["detail"] == "lease_ended"


async def test_a_lapsed_lease_s_orders_are_never_handed_out_before_the_sweep(w: World) -> None:
    """The lease ended by its time while nothing had swept it yet: the vehicle's next
    poll must not get the former holder's go_to (the sweep runs on its own beat, so the
    poll ends the lease itself first)."""
    v = await w.vehicle()
    op = await w.operator_in_control(v, duration_s=60)
    cid = await w.queued(op, v, GO_TO, ttl_s=600)
    w.clock.advance(61)  # past the lease, long before the command's own expiry
    handed = await w.poll(v)
    assert [c["type"] for c in handed] == ["keep_station"]  # the server's hold, not the go_to
    assert handed[0]["issued_by"] == "system"
    cmd = await w.command(cid)
    assert cmd["status"] == "cancelled" and cmd["history"][-1]["detail"] == "lease_ended"
