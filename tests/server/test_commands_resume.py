"""A vehicle that starts its instance again says what it still has in hand
(``active_commands``): the server fails what nothing on the vehicle will finish, and
tells it to abort what the server has ended (docs/commands.md, "A vehicle resumes")."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable
from typing import Any

import httpx
import pytest

from server.settings import Settings
from tests.factories import ADMIN
from tests.server.commanding import GO_TO, KEEP, Vehicle, World, statuses, world

pytestmark = pytest.mark.usefixtures("store_backend")


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    async with world(make_settings(ack_timeout_s=10, long_poll_max=1)) as w:
        yield w


async def _restart(w: World, v: Vehicle, active: list[str] | None) -> httpx.Response:
    body: dict[str, Any] = {"vehicle_id": v.vehicle_id}
    if active is not None:
        body["active_commands"] = active
    return await w.http.post("/upper/start_instance", headers=v.headers, json=body)


async def _executing(w: World, v: Vehicle, command: dict[str, Any]) -> str:
    op = await w.operator_in_control(v)
    cid = await w.queued(op, v, command)
    assert [c["command_id"] for c in await w.poll(v)] == [cid]
    await w.ack(v, (cid, "accepted"), (cid, "executing"))
    return cid


async def test_a_command_the_vehicle_no_longer_has_is_failed_when_it_resumes(w: World) -> None:
    v = await w.vehicle()
    cid = await _executing(w, v, GO_TO)

    r = await _restart(w, v, [])
    assert r.status_code == 200, r.text
    assert r.json()["resumed"] is True and r.json()["abort"] == []
    cmd = await w.command(cid)
    assert cmd["status"] == "failed"
    assert statuses(cmd)[-1] == "failed"
    assert "the vehicle resumed without it" in cmd["history"][-1]["detail"]
    events = (await w.http.get("/api/events", headers=ADMIN, params={"kind": "command"})).json()[
        "events"
    ]
    assert any(e["data"].get("command_id") == cid and e["data"].get("status") == "failed"
               for e in events), events  # fmt: skip
    # Ended on the server's word: an ack of it later is recorded, leaves it failed, and
    # is answered with abort, as for a cancelled one.
    assert (await w.ack(v, (cid, "done")))["abort"] == [cid]
    cmd = await w.command(cid)
    assert cmd["status"] == "failed" and "ignored, already failed" in cmd["history"][-1]["detail"]


async def test_a_dropped_command_still_carried_out_elsewhere_is_aborted(w: World) -> None:
    """A second agent started with the vehicle's token (a failover left running) says it has
    nothing: the first, still driving the command, is told to abort it, by its long poll
    or by its next ack."""
    v = await w.vehicle()
    cid = await _executing(w, v, GO_TO)
    polling = w.long_poll(v)
    await w.poll_open(v)
    r = await _restart(w, v, [])
    assert r.status_code == 200 and (await w.command(cid))["status"] == "failed"
    assert (await asyncio.wait_for(polling, 10))["abort"] == [cid]
    # An ack of it later, as of any command the server ended, is answered with abort.
    assert (await w.ack(v, (cid, "executing")))["abort"] == [cid]
    assert (await w.command(cid))["status"] == "failed"


async def test_what_the_vehicle_names_stays_as_it_was(w: World) -> None:
    v = await w.vehicle()
    cid = await _executing(w, v, KEEP)
    r = await _restart(w, v, [cid])
    assert r.status_code == 200 and r.json()["abort"] == []
    assert (await w.command(cid))["status"] == "executing"
    # An ack still to come is the vehicle's: it ends the command as the vehicle says.
    await w.ack(v, (cid, "done"))
    assert (await w.command(cid))["status"] == "done"


async def test_a_vehicle_that_says_nothing_changes_nothing(w: World) -> None:
    """An older agent, or a client of the contract that does not send the field."""
    v = await w.vehicle()
    cid = await _executing(w, v, GO_TO)
    r = await _restart(w, v, None)
    assert r.status_code == 200 and r.json()["abort"] == []
    assert (await w.command(cid))["status"] == "executing"


async def test_commands_not_yet_acknowledged_are_left_to_redelivery(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    queued = await w.queued(op, v, GO_TO)
    r = await _restart(w, v, [])
    assert r.status_code == 200 and r.json()["abort"] == []
    assert (await w.command(queued))["status"] == "queued"
    assert [c["command_id"] for c in await w.poll(v)] == [queued]


async def test_what_the_server_ended_or_does_not_know_is_to_be_aborted(w: World) -> None:
    v = await w.vehicle()
    cid = await _executing(w, v, GO_TO)
    r = await w.http.post("/client/cancel_command", headers=ADMIN, json={"command_id": cid})
    assert r.status_code == 200, r.text
    r = await _restart(w, v, [cid, "not-a-command", cid])
    assert r.status_code == 200, r.text
    assert r.json()["abort"] == [cid, "not-a-command"]
    assert (await w.command(cid))["status"] == "cancelled"


async def test_another_instances_command_is_not_touched(w: World) -> None:
    one, two = await w.vehicle(), await w.vehicle()
    theirs = await _executing(w, two, GO_TO)
    r = await _restart(w, one, [theirs])
    assert r.status_code == 200 and r.json()["abort"] == [theirs]
    assert (await w.command(theirs))["status"] == "executing"


@pytest.mark.parametrize(
    "active, field",
    [
        ([""], "active_commands.0"),
        (["x" * 65], "active_commands.0"),
        ([7], "active_commands.0"),
        (["c"] * 1025, "active_commands"),
        ("c-1", "active_commands"),
    ],
)
async def test_a_bad_list_is_422_naming_it(w: World, active: Any, field: str) -> None:
    v = await w.vehicle()
    r = await w.http.post(
        "/upper/start_instance",
        headers=v.headers,
        json={"vehicle_id": v.vehicle_id, "active_commands": active},
    )
    assert r.status_code == 422, r.text
    assert field in [d["field"] for d in r.json()["error"]["details"]], r.text
