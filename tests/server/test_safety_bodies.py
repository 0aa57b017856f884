"""A misspelt field of a safety setting is a 422 naming it, never a setting changed
otherwise: a failsafe policy (``acton``: the default policy would replace the one meant),
a zone (``vehicle``: a no-go zone would hold every vehicle), a grant (``operator_timeout``:
a lease with no liveness guard). What a client read may be sent back whole."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from typing import Any

import pytest

from server.settings import Settings
from tests.factories import ADMIN
from tests.server.commanding import World, world
from tests.server.test_obstacles import polygon

pytestmark = pytest.mark.usefixtures("store_backend")

PIER = [(40.0, -30.0), (60.0, -30.0), (60.0, 30.0), (40.0, 30.0)]


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    async with world(make_settings()) as w:
        yield w


def refused(r: Any, field: str) -> None:
    assert r.status_code == 422, r.text
    [detail] = r.json()["error"]["details"]
    assert detail["field"] == field and detail["message"].startswith("not a field of this body")


async def test_a_misspelt_failsafe_field_is_422_and_the_policy_is_kept(w: World) -> None:
    boat = await w.vehicle()
    url = f"/api/vehicles/{boat.vehicle_id}/failsafe"
    home = {"action": "return_home", "after_s": 20.0, "home": {"lat": 43.9, "lon": 15.4}}
    r = await w.http.put(url, headers=ADMIN, json=home)
    assert r.status_code == 200, r.text
    policy = r.json()["failsafe"]
    refused(await w.http.put(url, headers=ADMIN, json={"acton": "stop"}), "acton")
    assert (await w.http.get(url, headers=ADMIN)).json()["failsafe"] == policy
    # the policy as read, sent back (its version with it): taken, numbered anew
    r = await w.http.put(url, headers=ADMIN, json={**policy, "after_s": 25.0})
    assert r.status_code == 200, r.text
    assert r.json()["failsafe"]["after_s"] == 25.0
    assert r.json()["failsafe"]["version"] > policy["version"]


async def test_a_misspelt_zone_field_is_422_and_no_zone_is_drawn(w: World) -> None:
    boat = await w.vehicle()
    body = {"name": "pier", "kind": "no_go", "polygon": polygon(PIER)}
    r = await w.http.post("/api/zones", headers=ADMIN, json={**body, "vehicle": [boat.vehicle_id]})
    refused(r, "vehicle")
    refused(
        await w.http.post("/api/zones", headers=ADMIN, json={**body, "clearance": 5}), "clearance"
    )
    assert (await w.http.get("/api/zones", headers=ADMIN)).json()["zones"] == []
    r = await w.http.post("/api/zones", headers=ADMIN, json=body)
    assert r.status_code == 201, r.text
    zone = r.json()
    url = f"/api/zones/{zone['zone_id']}"
    refused(await w.http.patch(url, headers=ADMIN, json={"nmae": "pier 4"}), "nmae")
    # the zone as read, sent back whole with a change: taken
    r = await w.http.patch(url, headers=ADMIN, json={**zone, "name": "pier 4"})
    assert r.status_code == 200 and r.json()["name"] == "pier 4", r.text


async def test_a_misspelt_grant_field_is_422_and_nothing_is_granted(w: World) -> None:
    boat = await w.vehicle()
    op = await w.person("operator", boat)
    body = {"instance_id": boat.instance_id, "user": op.username, "duration_s": 600}
    r = await w.http.post(
        "/client/grant_control", headers=ADMIN, json={**body, "operator_timeout": 30}
    )
    refused(r, "operator_timeout")
    r = await w.http.post(
        "/client/connect_instance", headers=ADMIN, json={"instance_id": boat.instance_id}
    )
    assert r.json()["instance"]["control"] is None, r.text
    r = await w.http.post(
        "/client/grant_control", headers=ADMIN, json={**body, "operator_timeout_s": 30}
    )
    assert r.status_code == 200 and r.json()["operator_timeout_s"] == 30, r.text
