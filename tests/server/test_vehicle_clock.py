"""A vehicle whose clock is off (no GPS time, no NTP at sea) and says by how much
(``clock_offset_s``, from the ``server_time`` of its calls, as ``fleet-agent`` does):
its samples, dated by its clock, are judged by the server's clock turned into its
own. A clock ten minutes fast used to freeze its position (every sample "ahead");
one two minutes slow made every position stale, so a command with ``max_drift_m``
waited until it expired and every sample showed as replayed."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from datetime import timedelta
from typing import Any

import pytest

from server.settings import Settings
from tests.factories import ADMIN, sample
from tests.server.commanding import KEEP, Vehicle, World, world

pytestmark = pytest.mark.usefixtures("store_backend")

HERE = (43.9000, 15.4000)


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    async with world(make_settings()) as w:
        yield w


async def _report(
    w: World, v: Vehicle, seq: int, fast_s: float, offset_s: float | None, lat: float
) -> dict[str, Any]:
    """A sample taken now by a vehicle clock ``fast_s`` ahead of the server's (behind
    when negative); the call says ``offset_s`` as its clock offset (None: it does not)."""
    ts = w.clock() + timedelta(seconds=fast_s)
    body: dict[str, Any] = {
        "instance_id": v.instance_id,
        "samples": [sample(seq, ts=ts, lat=lat, lon=HERE[1])],
        "sent_at": ts.isoformat(),
    }
    if offset_s is not None:
        body["clock_offset_s"] = offset_s
    r = await w.http.post("/upper/update_param", headers=v.headers, json=body)
    assert r.status_code == 200, r.text
    return dict(r.json())


async def _position(w: World, v: Vehicle) -> dict[str, Any] | None:
    r = await w.http.get(f"/api/vehicles/{v.vehicle_id}", headers=ADMIN)
    assert r.status_code == 200, r.text
    position: dict[str, Any] | None = r.json()["position"]
    return position


async def test_a_clock_ten_minutes_fast_that_says_so_moves_the_position(w: World) -> None:
    v = await w.vehicle()
    await _report(w, v, 1, 600, -600.0, HERE[0])
    w.clock.advance(1)
    await _report(w, v, 2, 600, -600.0, HERE[0] + 0.001)
    position = await _position(w, v)
    assert position is not None and position["seq"] == 2


async def test_a_clock_ten_minutes_fast_that_does_not_say_so_is_ahead(w: World) -> None:
    """Without its offset the server takes the clocks as in step: a sample dated more
    than 5 minutes ahead is stored but never the position (a GPS glitch: 2099)."""
    v = await w.vehicle()
    await _report(w, v, 1, 600, None, HERE[0])
    assert await _position(w, v) is None
    r = await w.http.get(f"/api/vehicles/{v.vehicle_id}/telemetry", headers=ADMIN)
    assert [s["seq"] for s in r.json()["samples"]] == [1]


async def test_a_clock_two_minutes_slow_that_says_so_gets_a_command_with_max_drift(
    w: World,
) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    await _report(w, v, 1, -120, 120.0, HERE[0])
    cid = await w.queued(op, v, {**KEEP, "max_drift_m": 8}, ttl_s=600)
    handed = await w.poll(v)
    assert [c["command_id"] for c in handed] == [cid]


async def test_a_clock_two_minutes_slow_that_does_not_say_so_holds_a_command_with_max_drift(
    w: World,
) -> None:
    """Its positions read two minutes old: no drift can be judged by them."""
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    await _report(w, v, 1, -120, None, HERE[0])
    cid = await w.queued(op, v, {**KEEP, "max_drift_m": 8}, ttl_s=600)
    assert await w.poll(v) == []
    assert (await w.command(cid))["status"] == "queued"
