"""A control mode dated by the vehicle (``update_fbmessage.control_mode_since``, an
extension): a failsafe taken while the link was down is recorded as begun when the
vehicle took it, held between the instance's start and the server's now."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from datetime import timedelta
from typing import Any

import pytest

from fleet_protocol import format_ts, parse_ts
from server.settings import Settings
from tests.factories import ADMIN
from tests.server.commanding import Vehicle, World, world

pytestmark = pytest.mark.usefixtures("store_backend")


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    async with world(make_settings()) as w:
        yield w


async def said(w: World, me: Vehicle, mode: str, since: Any) -> None:
    body = {"instance_id": me.instance_id, "acks": [], "control_mode": mode}
    if since is not None:
        body["control_mode_since"] = since
    r = await w.http.post("/upper/update_fbmessage", headers=me.headers, json=body)
    assert r.status_code == 200, r.text


async def newest(w: World, me: Vehicle, kind: str) -> dict[str, Any]:
    r = await w.http.get("/api/events", headers=ADMIN, params={"vehicle_id": me.vehicle_id})
    found: dict[str, Any] = [e for e in r.json()["events"] if e["kind"] == kind][-1]
    return found


async def test_a_failsafe_is_dated_when_the_vehicle_took_it(w: World) -> None:
    me = await w.vehicle()
    started = w.clock()
    w.clock.advance(120)  # the link was down; the vehicle took its failsafe 90 s ago
    await said(w, me, "failsafe", format_ts(started + timedelta(seconds=30)))
    entered = await newest(w, me, "failsafe_entered")
    assert parse_ts(entered["at"]) == w.clock()
    assert parse_ts(entered["data"]["since"]) == started + timedelta(seconds=30)
    assert entered["data"]["since"] == format_ts(started + timedelta(seconds=30))  # to the ms
    mode = await newest(w, me, "control_mode")
    assert mode["data"]["since"] == entered["data"]["since"]

    w.clock.advance(10)
    await said(w, me, "idle", format_ts(w.clock() + timedelta(hours=1)))  # a clock ahead
    left = await newest(w, me, "failsafe_left")
    assert parse_ts(left["data"]["since"]) == w.clock()  # never in the future

    await said(w, me, "failsafe", format_ts(started - timedelta(days=3)))  # a clock behind
    again = await newest(w, me, "failsafe_entered")
    assert parse_ts(again["data"]["since"]) == started  # not before the instance began

    await said(w, me, "idle", None)  # an agent that does not say: the call's time alone
    assert "since" not in (await newest(w, me, "failsafe_left"))["data"]


async def test_a_since_that_is_not_a_time_is_422_naming_it(w: World) -> None:
    me = await w.vehicle()
    body = {"instance_id": me.instance_id, "control_mode": "failsafe", "control_mode_since": "soon"}
    r = await w.http.post("/upper/update_fbmessage", headers=me.headers, json=body)
    assert r.status_code == 422
    assert r.json()["error"]["details"][0]["field"] == "control_mode_since"
