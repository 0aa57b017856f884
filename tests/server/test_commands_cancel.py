"""Cancel: the vehicle told to abort (long poll, ack), once; who may cancel what."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable
from typing import Any

import pytest

from server.settings import Settings
from tests.factories import ADMIN
from tests.server.commanding import GO_TO, STOP, Person, World, world

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    async with world(make_settings(ack_timeout_s=10, long_poll_max=1)) as w:
        yield w


async def test_the_issuer_cancels_and_the_vehicle_is_told_to_abort(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    cid = await w.queued(op, v, GO_TO)
    await w.poll(v)
    r = await w.http.post("/client/cancel_command", headers=op.headers, json={"command_id": cid})
    assert r.status_code == 200, r.text
    assert r.json()["status"] == "cancelled"
    assert (await w.ack(v))["abort"] == [cid]
    assert (await w.ack(v))["abort"] == []


async def test_a_long_poll_returns_at_once_with_a_running_command_cancelled(w: World) -> None:
    """A go_to under way sends no ack for minutes: its cancel reaches the vehicle through
    the long poll it keeps open, at once, and only once."""
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    cid = await w.queued(op, v, GO_TO)
    await w.poll(v)
    await w.ack(v, (cid, "accepted"), (cid, "executing"))
    polling = w.long_poll(v)
    await w.poll_open(v)
    r = await w.http.post("/client/cancel_command", headers=op.headers, json={"command_id": cid})
    assert r.status_code == 200 and r.json()["status"] == "cancelled", r.text
    answer = await asyncio.wait_for(polling, 10)  # well before its 30 s
    assert answer["abort"] == [cid] and answer["commands"] == []
    assert (await w.poll_answer(v))["abort"] == []
    assert (await w.ack(v))["abort"] == []


async def test_a_cancel_racing_a_poll_is_told_once(w: World) -> None:
    """Polls that read the commands while a cancel is being written (the store still
    listing the command as active) neither hand it back nor tell its abort twice."""
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    cid = await w.queued(op, v, GO_TO)
    await w.poll(v)
    await w.ack(v, (cid, "executing"))
    cancel = w.http.post("/client/cancel_command", headers=op.headers, json={"command_id": cid})
    r, *answers = await asyncio.gather(cancel, *(w.poll_answer(v) for _ in range(8)))
    assert r.status_code == 200 and r.json()["status"] == "cancelled", r.text
    answers += [await w.poll_answer(v), await w.ack(v)]
    assert all(a.get("commands", []) == [] for a in answers)
    assert [c for a in answers for c in a["abort"]] == [cid]


async def test_cancelling_a_final_command_leaves_it_as_it_is(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    cid = await w.queued(op, v, GO_TO)
    await w.ack(v, (cid, "done"))
    r = await w.http.post("/client/cancel_command", headers=op.headers, json={"command_id": cid})
    assert r.status_code == 200
    assert r.json()["status"] == "done"


async def test_cancel_command_refusals(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    cid = await w.queued(op, v, GO_TO)
    bystander = await w.person("operator", v)
    viewer = await w.person("viewer", v)
    stranger = await w.person("operator")
    cases = [
        ({}, {"command_id": cid}, 401),
        (viewer.headers, {"command_id": cid}, 403),
        (stranger.headers, {"command_id": cid}, 404),  # as an unknown command
        (bystander.headers, {"command_id": cid}, 409),
        (op.headers, {"command_id": "c-nope"}, 404),
        (op.headers, {"command_id": ""}, 422),
        (op.headers, {}, 422),
    ]
    for headers, body, status in cases:
        r = await w.http.post("/client/cancel_command", headers=headers, json=body)
        assert r.status_code == status, (body, r.text)
    assert (await w.command(cid))["status"] == "queued"


async def _cancel(w: World, who: dict[str, str], command_id: str) -> tuple[int, dict[str, Any]]:
    r = await w.http.post("/client/cancel_command", headers=who, json={"command_id": command_id})
    return r.status_code, r.json()


async def test_a_managers_stop_is_not_cancelled_by_the_holder(w: World) -> None:
    """The field manager stops the vehicle: the operator holding control may not undo it
    (403, a question of standing); the manager who sent it, another manager of the
    vehicle or an admin may."""
    v = await w.vehicle()
    holder = await w.operator_in_control(v)
    boss, other_boss = await w.person("manager", v), await w.person("manager", v)
    stops = []
    for _ in range(4):  # each handed out before the next (a queued one the next stands for)
        stops.append(await w.queued(boss, v, STOP))
        assert [c["command_id"] for c in await w.poll(v)] == [stops[-1]]
    status, body = await _cancel(w, holder.headers, stops[0])
    assert status == 403, body
    assert body["error"]["code"] == "forbidden"
    assert "manager" in body["error"]["message"]
    assert (await w.command(stops[0]))["status"] == "delivered"  # the vehicle has it still
    for who, stop in zip((boss.headers, other_boss.headers, ADMIN), stops[1:], strict=True):
        status, body = await _cancel(w, who, stop)
        assert (status, body["status"]) == (200, "cancelled"), body


async def test_an_admins_stop_is_not_cancelled_by_the_holder_either(w: World) -> None:
    v = await w.vehicle()
    holder = await w.operator_in_control(v)
    boss = await w.person("manager", v)
    admin = Person("admin", ADMIN)
    stop = await w.queued(admin, v, STOP)
    await w.poll(v)  # handed out: the next stop does not stand for it
    other = await w.queued(admin, v, STOP)
    assert (await _cancel(w, holder.headers, stop))[0] == 403
    assert (await _cancel(w, boss.headers, stop))[1]["status"] == "cancelled"
    assert (await _cancel(w, ADMIN, other))[1]["status"] == "cancelled"


async def test_an_operators_stop_is_still_cancelled_by_the_holder(w: World) -> None:
    v = await w.vehicle()
    holder = await w.operator_in_control(v)
    other_op = await w.person("operator", v)
    stop = await w.queued(other_op, v, STOP)  # any operator with access may stop
    status, body = await _cancel(w, holder.headers, stop)
    assert (status, body["status"]) == (200, "cancelled"), body
