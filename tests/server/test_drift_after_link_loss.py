"""``max_drift_m`` judged by where the vehicle is, not where it was last heard: a
command queued while the vehicle was out of contact waits, once it is back, for a
position that is current; its positions of the meantime (its outbox) do not count."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable
from datetime import timedelta

import pytest

from server.settings import Settings
from tests.factories import sample
from tests.server.commanding import KEEP, Vehicle, World, world

pytestmark = pytest.mark.usefixtures("store_backend")

HERE = (43.9000, 15.4000)
AWAY = (43.9003, 15.4000)  # about 33 m north


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    async with world(make_settings()) as w:
        yield w


async def _report(w: World, v: Vehicle, seq: int, ago_s: float, at: tuple[float, float]) -> None:
    ts = w.clock() - timedelta(seconds=ago_s)
    body = {"instance_id": v.instance_id, "samples": [sample(seq, ts=ts, lat=at[0], lon=at[1])]}
    r = await w.http.post("/upper/update_param", headers=v.headers, json=body)
    assert r.status_code == 200, r.text


async def _queued_while_away(w: World) -> tuple[Vehicle, str]:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    await _report(w, v, 1, 0, HERE)
    w.clock.advance(60)  # the link is down; the vehicle drifts meanwhile
    cid = await w.queued(op, v, {**KEEP, "max_drift_m": 8}, ttl_s=600)
    return v, cid


async def test_a_command_waits_for_a_current_position_then_expires_as_drifted(w: World) -> None:
    v, cid = await _queued_while_away(w)
    assert await w.poll(v) == []  # back in contact: only a minute-old position is known
    assert (await w.command(cid))["status"] == "queued"
    await _report(w, v, 2, 40, AWAY)  # its outbox: where it was 40 s ago
    assert await w.poll(v) == []
    await _report(w, v, 3, 0, AWAY)  # now: 33 m from where it was told to keep station
    assert await w.poll(v) == []
    cmd = await w.command(cid)
    assert cmd["status"] == "expired" and cmd["history"][-1]["detail"] == "drifted"


async def test_a_current_position_close_by_hands_it_out_at_once(w: World) -> None:
    v, cid = await _queued_while_away(w)
    poll = asyncio.create_task(w.poll(v, wait_s=10))
    await _report(w, v, 2, 0, HERE)  # the long poll is answered when it comes
    async with asyncio.timeout(5):
        handed = await poll
    assert [c["command_id"] for c in handed] == [cid]
