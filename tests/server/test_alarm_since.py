"""Since when each alarm is so (``VehicleView.alarms[].since``, an extension): a breach
or a low battery from the time of the sample that raised it, kept while it lasts, gone
when it clears; a failsafe from when the vehicle says it entered it."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable
from datetime import datetime, timedelta
from typing import Any

import httpx
import pytest
from asgi_lifespan import LifespanManager

from fleet_protocol import format_ts
from server.app import create_app
from server.settings import Settings
from server.storage import open_store
from tests.factories import ADMIN, FakeClock, sample
from tests.server.commanding import Vehicle, World, eventually, world
from tests.server.test_obstacles import at
from tests.server.test_zones import no_go, zone

pytestmark = pytest.mark.usefixtures("store_backend")

#: A second no-go square, 50..80 m east: it overlaps the pier (40..60 m) from 50 to 60 m.
QUAY = [(50.0, -30.0), (80.0, -30.0), (80.0, 30.0), (50.0, 30.0)]


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    async with world(make_settings()) as w:
        yield w


async def report(
    w: World, me: Vehicle, seq: int, ts: datetime, battery: float = 80.0, x: float = 0.0
) -> None:
    lat, lon = at(x, 0).values()
    body = {
        "instance_id": me.instance_id,
        "samples": [sample(seq, ts=ts, lat=lat, lon=lon, battery_pct=battery)],
    }
    r = await w.http.post("/upper/update_param", headers=me.headers, json=body)
    assert r.status_code == 200, r.text


async def alarms(w: World, me: Vehicle) -> list[dict[str, Any]]:
    r = await w.http.get(f"/api/vehicles/{me.vehicle_id}", headers=ADMIN)
    assert r.status_code == 200, r.text
    found: list[dict[str, Any]] = r.json()["alarms"]
    return found


async def until_alarms(w: World, me: Vehicle, want: Callable[[list[dict[str, Any]]], bool]) -> Any:
    """The vehicle's alarms once ``want`` holds of them (the watch acts on its own beat)."""

    async def holds() -> bool:
        return want(await alarms(w, me))

    await eventually(holds)
    return await alarms(w, me)


async def test_a_low_battery_is_dated_by_the_sample_that_raised_it_until_it_ends(
    w: World,
) -> None:
    me = await w.vehicle()
    put = await w.http.put(
        f"/api/vehicles/{me.vehicle_id}/failsafe", headers=ADMIN, json={"low_battery_pct": 20.0}
    )
    assert put.status_code == 200, put.text
    await report(w, me, 1, w.clock(), battery=80.0)
    assert await alarms(w, me) == []

    w.clock.advance(60)
    raised = w.clock() - timedelta(seconds=5)  # the sample is older than its arrival
    await report(w, me, 2, raised, battery=15.0)
    [low] = await until_alarms(w, me, lambda a: [x["kind"] for x in a] == ["low_battery"])
    assert low["since"] == format_ts(raised)

    w.clock.advance(60)
    await report(w, me, 3, w.clock(), battery=14.0)  # still low: since as it was
    [low] = await until_alarms(w, me, lambda a: bool(a) and "14 %" in a[0]["message"])
    assert low["since"] == format_ts(raised)

    w.clock.advance(60)
    await report(w, me, 4, w.clock(), battery=30.0)  # recovered: the alarm and its date go
    assert await until_alarms(w, me, lambda a: a == []) == []

    w.clock.advance(60)
    again = w.clock()
    await report(w, me, 5, again, battery=10.0)  # low again: dated anew
    [low] = await until_alarms(w, me, lambda a: bool(a))
    assert low["since"] == format_ts(again)


async def test_a_sample_dated_ahead_of_the_server_dates_its_alarm_now(w: World) -> None:
    me = await w.vehicle()
    put = await w.http.put(
        f"/api/vehicles/{me.vehicle_id}/failsafe", headers=ADMIN, json={"low_battery_pct": 20.0}
    )
    assert put.status_code == 200, put.text
    # A clock ahead, within the five minutes that still make the sample the position
    # (one further ahead judges nothing: test_watch_now).
    await report(w, me, 1, w.clock() + timedelta(minutes=4), battery=15.0)
    [low] = await until_alarms(w, me, lambda a: bool(a))
    assert low["since"] == format_ts(w.clock())  # never in the future


async def test_each_breach_keeps_its_own_since_while_the_zones_breached_change(
    w: World,
) -> None:
    pier = (await zone(w, no_go()))["zone_id"]
    quay = (await zone(w, no_go("quay", QUAY)))["zone_id"]
    me = await w.vehicle()
    await report(w, me, 1, w.clock(), x=0)  # at home: nothing wrong

    def since_of(found: list[dict[str, Any]]) -> dict[str, str]:
        return {a["zone_id"]: a["since"] for a in found if a["kind"] == "no_go_zone"}

    w.clock.advance(30)
    into_pier = w.clock()
    await report(w, me, 2, into_pier, x=45)  # the pier alone
    got = await until_alarms(w, me, lambda a: set(since_of(a)) == {pier})
    assert since_of(got) == {pier: format_ts(into_pier)}

    w.clock.advance(30)
    into_quay = w.clock()
    await report(w, me, 3, into_quay, x=55)  # the pier and the quay
    got = await until_alarms(w, me, lambda a: set(since_of(a)) == {pier, quay})
    assert since_of(got) == {pier: format_ts(into_pier), quay: format_ts(into_quay)}

    w.clock.advance(30)
    await report(w, me, 4, w.clock(), x=70)  # the quay alone: still since it entered it
    got = await until_alarms(w, me, lambda a: set(since_of(a)) == {quay})
    assert since_of(got) == {quay: format_ts(into_quay)}

    w.clock.advance(30)
    await report(w, me, 5, w.clock(), x=0)
    assert await until_alarms(w, me, lambda a: a == []) == []


async def fb(w: World, me: Vehicle, mode: str, since: datetime | None) -> None:
    body: dict[str, Any] = {"instance_id": me.instance_id, "acks": [], "control_mode": mode}
    if since is not None:
        body["control_mode_since"] = format_ts(since)
    r = await w.http.post("/upper/update_fbmessage", headers=me.headers, json=body)
    assert r.status_code == 200, r.text


async def test_a_failsafe_is_dated_when_the_vehicle_entered_it(w: World) -> None:
    me = await w.vehicle()
    w.clock.advance(120)
    entered = w.clock() - timedelta(seconds=90)  # taken while the link was down
    await fb(w, me, "failsafe", entered)
    [alarm] = await alarms(w, me)
    assert alarm["kind"] == "failsafe" and alarm["since"] == format_ts(entered)
    listed = (await w.http.get("/api/vehicles", headers=ADMIN)).json()["vehicles"]
    [row] = [v for v in listed if v["vehicle_id"] == me.vehicle_id]
    assert row["alarms"][0]["since"] == format_ts(entered)

    w.clock.advance(10)
    await fb(w, me, "failsafe", w.clock())  # said again: it entered it when it first said
    assert (await alarms(w, me))[0]["since"] == format_ts(entered)

    await fb(w, me, "idle", None)
    assert await alarms(w, me) == []
    await fb(w, me, "failsafe", None)  # an agent that does not say when: not known
    [alarm] = await alarms(w, me)
    assert alarm["kind"] == "failsafe" and alarm["since"] is None


class _SlowFirstRead:
    """A collection whose first read by id takes a while (a store under load): the
    judgement of a vehicle's first sample is still reading when its next one comes."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.reads = 0

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    async def get(self, _id: Any) -> Any:
        self.reads += 1
        if self.reads == 1:
            await asyncio.sleep(0.3)  # the store's delay, not the test's wait
        return await self.inner.get(_id)


async def test_samples_are_judged_in_the_order_they_came(
    make_settings: Callable[..., Settings],
) -> None:
    """The first sample (at home) was still being judged when the second (in the pier)
    came: the second raised the breach, then the first, finishing last, cleared it, and
    the boat in the pier had no alarm until its next sample."""
    settings = make_settings()
    store = open_store(settings)
    plain = store._open
    store._open = lambda name: _SlowFirstRead(plain(name)) if name == "watch" else plain(name)  # type: ignore[method-assign]
    await store.load()
    clock = FakeClock()
    app = create_app(settings, clock=clock, store=store)
    try:
        async with LifespanManager(app, shutdown_timeout=30) as manager:
            transport = httpx.ASGITransport(app=manager.app)
            async with httpx.AsyncClient(transport=transport, base_url="http://test") as http:
                w = World(http, clock, app)
                pier = (await zone(w, no_go()))["zone_id"]
                me = await w.vehicle()
                await report(w, me, 1, w.clock(), x=0)  # at home: judged slowly
                w.clock.advance(1)
                into_pier = w.clock()
                await report(w, me, 2, into_pier, x=45)  # in the pier, before that ends

                async def breached() -> bool:
                    found = await alarms(w, me)
                    return [(a["kind"], a["zone_id"]) for a in found] == [("no_go_zone", pier)]

                await eventually(breached)
                await eventually(lambda: _settled(app))
                assert await breached(), await alarms(w, me)
    finally:
        await store.close()


async def _settled(app: Any) -> bool:
    """Every judgement of the samples done (the messages' handlers drained)."""
    await app.state.services.messages.drain()
    return True
