"""The zones as they were at a past time (``GET /api/zones?at=``, a replay's): each zone
as its latest change up to then left it, none deleted by then, none drawn after; seen as
the caller sees zones now; and retention keeps what any time since its cutoff needs."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from datetime import datetime, timedelta
from typing import Any

import pytest

from fleet_protocol import format_ts, parse_ts
from server.settings import Settings
from tests.factories import ADMIN
from tests.server.commanding import World, world
from tests.server.test_obstacles import polygon

pytestmark = pytest.mark.usefixtures("store_backend")

PIER = [(40.0, -30.0), (60.0, -30.0), (60.0, 30.0), (40.0, 30.0)]
MOVED = [(140.0, -30.0), (160.0, -30.0), (160.0, 30.0), (140.0, 30.0)]
BAY = [(-100.0, -100.0), (100.0, -100.0), (100.0, 100.0), (-100.0, 100.0)]


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    async with world(make_settings()) as w:
        yield w


async def zones_at(w: World, when: datetime | str, who: dict[str, str] = ADMIN) -> Any:
    at = when if isinstance(when, str) else format_ts(when)
    r = await w.http.get("/api/zones", headers=who, params={"at": at})
    assert r.status_code == 200, r.text
    return r.json()


def shapes(listed: Any) -> list[tuple[str, Any]]:
    return [(z["name"], z["polygon"]) for z in listed["zones"]]


async def test_the_zones_at_a_past_time_are_those_of_that_time(w: World) -> None:
    boat = await w.vehicle()
    r = await w.http.post(
        "/api/zones",
        headers=ADMIN,
        json={"name": "pier", "kind": "no_go", "polygon": polygon(PIER)},
    )
    assert r.status_code == 201, r.text
    pier = r.json()
    drawn = parse_ts(pier["created_at"])
    w.clock.advance(60)
    r = await w.http.patch(
        f"/api/zones/{pier['zone_id']}", headers=ADMIN, json={"polygon": polygon(MOVED)}
    )
    assert r.status_code == 200, r.text
    moved = parse_ts(r.json()["updated_at"])
    w.clock.advance(60)
    body = {"name": "bay", "kind": "operating_area", "polygon": polygon(BAY)}
    r = await w.http.post("/api/zones", headers=ADMIN, json={**body, "vehicles": [boat.vehicle_id]})
    assert r.status_code == 201, r.text
    bay = r.json()
    w.clock.advance(60)
    r = await w.http.delete(f"/api/zones/{pier['zone_id']}", headers=ADMIN)
    assert r.status_code == 200, r.text
    gone = w.clock() + timedelta(milliseconds=1)
    w.clock.advance(60)

    assert (await zones_at(w, drawn - timedelta(seconds=1)))["zones"] == []
    assert shapes(await zones_at(w, drawn)) == [("pier", polygon(PIER))]
    assert shapes(await zones_at(w, moved - timedelta(seconds=1))) == [("pier", polygon(PIER))]
    assert shapes(await zones_at(w, moved)) == [("pier", polygon(MOVED))]
    then = await zones_at(w, parse_ts(bay["created_at"]))
    assert shapes(then) == [("pier", polygon(MOVED)), ("bay", polygon(BAY))]
    assert then["version"] == bay["version"]
    assert then["zones"][1] == bay  # as it was served when drawn
    assert shapes(await zones_at(w, gone)) == [("bay", polygon(BAY))]
    now = (await w.http.get("/api/zones", headers=ADMIN)).json()
    assert await zones_at(w, w.clock()) == now

    # a user sees the zones of then as those of now: only those of the vehicles it sees
    stranger = await w.person("operator")
    assert shapes(await zones_at(w, parse_ts(bay["created_at"]), stranger.headers)) == [
        ("pier", polygon(MOVED))
    ]

    # the changes in a window, for each caller the zones it sees: a replay reads the set
    # again after each (a zone for every vehicle is everyone's: a manager's replay missed
    # them when it looked for them in the event log, where they name no vehicle)
    window = {"from": format_ts(drawn - timedelta(seconds=1)), "to": format_ts(w.clock())}

    async def changes(who: dict[str, str]) -> list[tuple[str, bool]]:
        r = await w.http.get("/api/zones/changes", headers=who, params=window)
        assert r.status_code == 200, r.text
        return [(c["zone_id"], c["deleted"]) for c in r.json()["changes"]]

    p, b = pier["zone_id"], bay["zone_id"]
    assert await changes(ADMIN) == [(p, False), (p, False), (b, False), (p, True)]
    assert await changes(stranger.headers) == [(p, False), (p, False), (p, True)]
    r = await w.http.get("/api/zones/changes", headers=ADMIN, params={"from": "x", "to": "y"})
    assert r.status_code == 422, r.text
    r = await w.http.get("/api/zones", headers=ADMIN, params={"at": "yesterday"})
    assert r.status_code == 422, r.text
    assert [d["field"] for d in r.json()["error"]["details"]] == ["at"]

    # retention: what any time since its cutoff needs is kept; the rest goes
    repo = w.services.zones.repo
    cutoff = parse_ts(bay["created_at"]) + timedelta(seconds=1)
    assert await repo.drop_versions_before(cutoff) == 1  # the pier's first shape
    assert shapes(await zones_at(w, cutoff)) == [("pier", polygon(MOVED)), ("bay", polygon(BAY))]
    assert shapes(await zones_at(w, gone)) == [("bay", polygon(BAY))]
    assert await repo.drop_versions_before(w.clock()) == 2  # the pier's moved shape, its end
    assert shapes(await zones_at(w, w.clock())) == [("bay", polygon(BAY))]


async def test_a_zone_drawn_before_versions_were_kept_has_its_past_from_then(w: World) -> None:
    """A store an older version wrote holds zones and no versions: such a zone is in the
    past set from when it was drawn, and its first change keeps its shape until then."""
    r = await w.http.post(
        "/api/zones",
        headers=ADMIN,
        json={"name": "pier", "kind": "no_go", "polygon": polygon(PIER)},
    )
    pier = r.json()
    assert await w.services.zones.repo.versions.delete({}) == 1  # as an older version left it
    drawn = parse_ts(pier["created_at"])
    w.clock.advance(60)
    assert (await zones_at(w, drawn - timedelta(seconds=1)))["zones"] == []
    assert shapes(await zones_at(w, w.clock())) == [("pier", polygon(PIER))]
    r = await w.http.patch(
        f"/api/zones/{pier['zone_id']}", headers=ADMIN, json={"polygon": polygon(MOVED)}
    )
    assert r.status_code == 200, r.text
    moved = parse_ts(r.json()["updated_at"])
    assert shapes(await zones_at(w, drawn)) == [("pier", polygon(PIER))]
    assert shapes(await zones_at(w, moved - timedelta(seconds=1))) == [("pier", polygon(PIER))]
    assert shapes(await zones_at(w, moved)) == [("pier", polygon(MOVED))]
