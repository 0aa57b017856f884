"""Delivery and life: get_control, update_fbmessage, expiry, redelivery, stop, drift (cancel:
test_commands_cancel.py)."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable

import pytest

from server.settings import Settings
from tests.factories import ADMIN
from tests.server.commanding import GO_TO, KEEP, STOP, World, eventually, statuses, world

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    async with world(make_settings(ack_timeout_s=10, long_poll_max=1)) as w:
        yield w


async def test_acks_move_the_command_through_its_life(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    cid = await w.queued(op, v, GO_TO)
    await w.poll(v)
    for status in ("accepted", "executing", "done"):
        assert (await w.ack(v, (cid, status)))["abort"] == []
    cmd = await w.command(cid)
    assert cmd["status"] == "done"
    assert statuses(cmd) == ["queued", "delivered", "accepted", "executing", "done"]


async def test_a_backward_ack_is_recorded_and_ignored(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    cid = await w.queued(op, v, GO_TO)
    await w.ack(v, (cid, "executing"))
    await w.ack(v, (cid, "accepted"))
    cmd = await w.command(cid)
    assert cmd["status"] == "executing"
    assert cmd["history"][-1]["status"] == "ack:accepted"


async def test_stop_jumps_the_queue_and_cancels_the_motion_before_it(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    first = await w.queued(op, v, GO_TO)
    second = await w.queued(op, v, KEEP)
    stop = await w.queued(op, v, STOP)
    after = await w.queued(op, v, GO_TO)
    assert [c["command_id"] for c in await w.poll(v)] == [stop, after]
    for cid in (first, second):
        cmd = await w.command(cid)
        assert cmd["status"] == "cancelled"
        assert cmd["history"][-1]["detail"] == "superseded_by_stop"


async def test_stop_is_handed_out_before_older_commands(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    go = await w.queued(op, v, GO_TO)
    await w.poll(v)
    await w.ack(v, (go, "accepted"))
    keep = await w.queued(op, v, KEEP)
    w.clock.advance(1)
    stop = await w.queued(op, v, STOP)
    # ``keep`` was queued before the stop: cancelled; ``go`` was accepted: left to the vehicle.
    assert [c["command_id"] for c in await w.poll(v)] == [stop]
    assert (await w.command(keep))["status"] == "cancelled"
    assert (await w.command(go))["status"] == "accepted"


async def test_an_expired_command_is_never_handed_out(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    cid = await w.queued(op, v, GO_TO, ttl_s=5)
    w.clock.advance(5)
    assert await w.poll(v) == []
    assert (await w.command(cid))["status"] == "expired"


async def test_a_delivered_unacknowledged_command_expires_and_is_aborted(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    cid = await w.queued(op, v, GO_TO, ttl_s=5)
    await w.poll(v)
    w.clock.advance(6)

    async def expired() -> bool:
        return (await w.command(cid))["status"] == "expired"

    await eventually(expired)  # the sweeper, on its own beat
    result = await w.ack(v, (cid, "accepted"))
    assert result["abort"] == [cid]
    cmd = await w.command(cid)
    assert cmd["status"] == "expired"
    assert cmd["history"][-1]["status"] == "ack:accepted"


async def test_an_unacknowledged_command_is_redelivered_after_the_ack_timeout(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    cid = await w.queued(op, v, GO_TO, ttl_s=120)
    assert [c["command_id"] for c in await w.poll(v)] == [cid]
    assert await w.poll(v) == []
    w.clock.advance(10)
    assert [c["command_id"] for c in await w.poll(v)] == [cid]
    assert await w.poll(v) == []
    await w.ack(v, (cid, "accepted"))
    w.clock.advance(30)
    assert await w.poll(v) == []


async def test_a_command_is_expired_as_drifted_when_the_vehicle_moved(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    await w.move_to(v, 1, 43.9, 15.4)
    command = {**GO_TO, "max_drift_m": 50}
    cid = await w.queued(op, v, command)
    w.clock.advance(1)
    await w.move_to(v, 2, 43.901, 15.4)  # about 111 m north
    assert await w.poll(v) == []
    cmd = await w.command(cid)
    assert cmd["status"] == "expired"
    assert cmd["history"][-1]["detail"] == "drifted"


async def test_a_long_poll_is_woken_by_a_submit(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    poll = asyncio.create_task(w.poll(v, wait_s=30))
    cid = await w.queued(op, v, GO_TO)
    got = await asyncio.wait_for(poll, 10)
    assert [c["command_id"] for c in got] == [cid]


async def test_a_long_poll_with_nothing_to_hand_out_ends_empty(w: World) -> None:
    v = await w.vehicle()
    assert await w.poll(v, wait_s=0.05) == []


async def test_open_long_polls_per_vehicle_are_bounded(w: World) -> None:
    v = await w.vehicle()
    op = await w.person("operator", v)
    first = w.long_poll(v)
    await w.poll_open(v)
    r = await w.http.get(
        "/upper/get_control", headers=v.headers, params={"instance_id": v.instance_id, "wait_s": 5}
    )
    assert r.status_code == 429
    assert r.json()["error"]["code"] == "rate_limited"
    assert "retry-after" in r.headers
    await w.queued(op, v, STOP)
    assert len((await asyncio.wait_for(first, 10))["commands"]) == 1


async def test_get_control_refusals(w: World) -> None:
    v, other = await w.vehicle(), await w.vehicle()
    op = await w.person("operator", v)
    cases: list[tuple[dict[str, str], dict[str, str | int], int]] = [
        ({}, {"instance_id": v.instance_id}, 401),
        (op.headers, {"instance_id": v.instance_id}, 403),
        (other.headers, {"instance_id": v.instance_id}, 404),  # not its own: as if none
        (v.headers, {"instance_id": "i-nope"}, 404),
        (v.headers, {"instance_id": v.instance_id, "wait_s": 31}, 422),
        (v.headers, {"instance_id": v.instance_id, "wait_s": "soon"}, 422),
        (v.headers, {}, 422),
    ]
    for headers, params, status in cases:
        r = await w.http.get("/upper/get_control", headers=headers, params=params)
        assert r.status_code == status, (params, r.text)
        assert "error" in r.json()


async def test_update_fbmessage_refusals(w: World) -> None:
    v, other = await w.vehicle(), await w.vehicle()
    good = {"instance_id": v.instance_id, "acks": []}
    cases = [
        ({}, good, 401),
        (ADMIN, good, 403),
        (other.headers, good, 404),
        (v.headers, {"instance_id": "i-nope"}, 404),
        (v.headers, {**good, "control_mode": "asleep"}, 422),
        (v.headers, {**good, "acks": [{"command_id": "c-1", "status": "queued"}]}, 422),
        *(
            (
                v.headers,
                {**good, "acks": [{"command_id": "c-1", "status": "done", "progress": p}]},
                422,
            )
            for p in (1.5, 50, -0.1)  # a fraction from 0 to 1, not a percentage
        ),
    ]
    for headers, body, status in cases:
        r = await w.http.post("/upper/update_fbmessage", headers=headers, json=body)
        assert r.status_code == status, (body, r.text)
        assert "error" in r.json()


async def test_an_ack_for_an_unknown_command_comes_back_in_abort(w: World) -> None:
    v = await w.vehicle()
    assert (await w.ack(v, ("c-never", "accepted")))["abort"] == ["c-never"]


async def test_finish_instance_cancels_what_is_pending(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    cid = await w.queued(op, v, GO_TO)
    r = await w.http.post(
        "/upper/finish_instance", headers=v.headers, json={"instance_id": v.instance_id}
    )
    assert r.status_code == 200, r.text
    cmd = await w.command(cid)
    assert cmd["status"] == "cancelled"
    assert cmd["history"][-1]["detail"] == "instance_finished"
    r = await w.http.get(
        "/upper/get_control", headers=v.headers, params={"instance_id": v.instance_id}
    )
    assert r.status_code == 409
    assert r.json()["error"]["code"] == "instance_finished"


async def test_get_fbmessage_shows_the_mode_and_recent_commands(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    first = await w.queued(op, v, GO_TO)
    w.clock.advance(1)
    second = await w.queued(op, v, KEEP)
    await w.ack(v, (first, "done"), control_mode="remote")
    viewer = await w.person("viewer", v)
    r = await w.http.get(
        "/client/get_fbmessage", headers=viewer.headers, params={"instance_id": v.instance_id}
    )
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["control_mode"] == "remote"
    assert [c["command_id"] for c in body["commands"]] == [second, first]
    assert [c["status"] for c in body["commands"]] == ["queued", "done"]


async def test_get_fbmessage_and_get_command_refusals(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    cid = await w.queued(op, v, GO_TO)
    stranger = await w.person("viewer")
    r = await w.http.get(
        "/client/get_fbmessage", headers=stranger.headers, params={"instance_id": v.instance_id}
    )
    assert r.status_code == 404
    r = await w.http.get(
        "/client/get_fbmessage", headers=op.headers, params={"instance_id": "i-nope"}
    )
    assert r.status_code == 404
    r = await w.http.get("/client/get_fbmessage", headers=op.headers)
    assert r.status_code == 422
    assert (await w.http.get(f"/api/commands/{cid}", headers=stranger.headers)).status_code == 404
    assert (await w.http.get("/api/commands/c-nope", headers=ADMIN)).status_code == 404
    assert (await w.http.get(f"/api/commands/{cid}")).status_code == 401


async def test_metrics_count_active_commands_by_status(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    await w.queued(op, v, GO_TO)
    await w.poll(v)
    await w.queued(op, v, KEEP)
    r = await w.http.get("/metrics")
    assert r.status_code == 200
    lines = r.text.splitlines()
    assert 'fleet_commands{status="delivered"} 1.0' in lines
    assert 'fleet_commands{status="queued"} 1.0' in lines


async def test_a_change_of_control_mode_is_an_event(w: World) -> None:
    v = await w.vehicle()
    await w.ack(v, control_mode="failsafe")
    await w.ack(v, control_mode="failsafe")
    r = await w.http.get(
        "/api/events", headers=ADMIN, params={"vehicle_id": v.vehicle_id, "kind": "control_mode"}
    )
    assert [e["data"]["control_mode"] for e in r.json()["events"]] == ["failsafe"]
