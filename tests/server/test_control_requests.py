"""Requests for control through HTTP: asked (once), listed for the managers and for their
makers, declined with a reason, bounded, refused, and dropped unanswered after their time."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from datetime import timedelta
from typing import Any

import pytest

from fleet_protocol import parse_ts
from server.settings import Settings
from tests.factories import ADMIN
from tests.server.commanding import GO_TO, World, eventually, world

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    async with world(make_settings(max_pending_requests=2)) as w:
        yield w


async def test_a_request_reaches_the_manager_and_a_grant_answers_it(w: World) -> None:
    v = await w.vehicle()
    op = await w.person("operator", v)
    boss = await w.person("manager", v)
    r = await w.client_post("request_control", op.headers, instance_id=v.instance_id)
    assert r.status_code == 200, r.text
    request = r.json()
    assert (request["username"], request["instance_id"]) == (op.username, v.instance_id)
    assert request["request_id"] and request["requested_at"]
    again = await w.client_post("request_control", op.headers, instance_id=v.instance_id)
    assert again.json()["request_id"] == request["request_id"]

    r = await w.http.get(
        "/client/control_requests", headers=boss.headers, params={"instance_id": v.instance_id}
    )
    assert r.status_code == 200
    assert [q["request_id"] for q in r.json()["requests"]] == [request["request_id"]]
    r = await w.http.get("/client/control_requests", headers=op.headers)
    assert r.json()["requests"] == []  # an operator answers none
    r = await w.http.get(
        "/client/control_requests", headers=boss.headers, params={"instance_id": "i-none"}
    )
    assert r.status_code == 404

    r = await w.grant(v, op.username, duration_s=60, by=boss.headers)
    assert r.status_code == 200, r.text
    lease = r.json()
    assert (lease["holder"], lease["granted_by"]) == (op.username, boss.username)
    assert parse_ts(lease["expires_at"]) == w.clock.now + timedelta(seconds=60)
    r = await w.http.get("/client/control_requests", headers=boss.headers)
    assert r.json()["requests"] == []
    assert (await w.submit(op, [v], GO_TO)).status_code == 202


async def test_a_manager_declines_a_request_and_the_requester_hears_why(w: World) -> None:
    v = await w.vehicle()
    op = await w.person("operator", v)
    boss = await w.person("manager", v)
    assert (
        await w.client_post("request_control", op.headers, instance_id=v.instance_id)
    ).is_success
    # an operator may not decline, and a request nobody made cannot be declined
    r = await w.client_post("deny_control", op.headers, instance_id=v.instance_id, user=op.username)
    assert r.status_code == 403, r.text
    r = await w.client_post("deny_control", boss.headers, instance_id=v.instance_id, user="someone")
    assert r.status_code == 404 and "someone" in r.json()["error"]["message"], r.text
    r = await w.client_post("deny_control", boss.headers,
        instance_id=v.instance_id, user=op.username, reason="divers in the water",
    )  # fmt: skip
    assert r.status_code == 200 and r.json() == {"ok": True}, r.text
    r = await w.http.get("/client/control_requests", headers=boss.headers)
    assert r.json()["requests"] == []
    r = await w.http.get("/api/events", headers=op.headers, params={"vehicle_id": v.vehicle_id})
    (denied,) = [e for e in r.json()["events"] if e["kind"] == "control_deny"]
    assert denied["data"] == {"user": op.username, "reason": "divers in the water"}
    assert denied["actor"] == boss.username
    # declined once, it may be asked for again
    assert (
        await w.client_post("request_control", op.headers, instance_id=v.instance_id)
    ).is_success
    r = await w.client_post(
        "deny_control", boss.headers, instance_id=v.instance_id, user="Not An Id"
    )
    assert r.status_code == 422
    # a reason is shown to people: no control characters, nor ones that reorder the text
    for reason in ["\x1b[2Jgo away", "two\nlines", "ok\u202etxet"]:
        r = await w.client_post("deny_control", boss.headers,
            instance_id=v.instance_id, user=op.username, reason=reason,
        )  # fmt: skip
        assert r.status_code == 422, r.text
        assert [d["field"] for d in r.json()["error"]["details"]] == ["reason"], r.text
        assert "shown on screens" in r.json()["error"]["details"][0]["message"]
    r = await w.http.get("/client/control_requests", headers=boss.headers)
    assert [q["username"] for q in r.json()["requests"]] == [op.username]  # still pending


async def test_a_requester_lists_its_own_pending_requests_until_answered_or_dropped(
    make_settings: Callable[..., Settings],
) -> None:
    """``mine=true``: the caller's own requests (a console that was reloaded still says
    "Requested…"), each with the time it is dropped unanswered."""
    async with world(make_settings(control_request_ttl_s=300)) as w:
        v, other = await w.vehicle(), await w.vehicle()
        op = await w.person("operator", v, other)
        boss = await w.person("manager", v, other)
        asked = (
            await w.client_post("request_control", op.headers, instance_id=v.instance_id)
        ).json()
        assert parse_ts(asked["expires_at"]) == parse_ts(asked["requested_at"]) + timedelta(
            seconds=300
        )
        w.clock.advance(1)
        await w.client_post("request_control", op.headers, instance_id=other.instance_id)
        again = (
            await w.client_post("request_control", op.headers, instance_id=v.instance_id)
        ).json()
        assert again == asked  # the first request stands, with its expiry

        async def mine(headers: dict[str, str], **params: str) -> list[str]:
            r = await w.http.get(
                "/client/control_requests", headers=headers, params={"mine": "true", **params}
            )
            assert r.status_code == 200, r.text
            return [q["instance_id"] for q in r.json()["requests"]]

        assert await mine(op.headers) == [v.instance_id, other.instance_id]  # oldest first
        assert await mine(op.headers, instance_id=other.instance_id) == [other.instance_id]
        assert await mine(boss.headers) == []  # the manager asked nothing
        r = await w.http.get(
            "/client/control_requests", headers=op.headers, params={"mine": "maybe"}
        )
        assert r.status_code == 422 and r.json()["error"]["details"][0]["field"] == "mine"

        await w.client_post(
            "deny_control", boss.headers, instance_id=v.instance_id, user=op.username
        )
        assert await mine(op.headers) == [other.instance_id]
        w.clock.advance(300)  # past the first's expiry, before the sweep ran
        assert await mine(op.headers) == []
        r = await w.http.get("/client/control_requests", headers=boss.headers)
        assert r.json()["requests"] == []  # nor is it offered to the manager


async def test_pending_requests_are_bounded(w: World) -> None:
    v = await w.vehicle()
    people = [await w.person("operator", v) for _ in range(3)]
    codes = [
        (await w.client_post("request_control", p.headers, instance_id=v.instance_id)).status_code
        for p in people
    ]
    assert codes == [200, 200, 429]


async def test_request_control_refusals(w: World) -> None:
    v = await w.vehicle()
    viewer = await w.person("viewer", v)
    stranger = await w.person("operator")
    op = await w.person("operator", v)
    cases = [
        ({}, {"instance_id": v.instance_id}, 401),
        (viewer.headers, {"instance_id": v.instance_id}, 403),
        (stranger.headers, {"instance_id": v.instance_id}, 404),  # as if there were none
        (v.headers, {"instance_id": v.instance_id}, 403),
        (op.headers, {"instance_id": "i-nope"}, 404),
        (op.headers, {}, 422),
    ]
    for headers, body, status in cases:
        r = await w.http.post("/client/request_control", headers=headers, json=body)
        assert r.status_code == status, (body, r.text)
    holder = await w.operator_in_control(v)
    r = await w.client_post("request_control", holder.headers, instance_id=v.instance_id)
    assert r.status_code == 409 and r.json()["error"]["code"] == "control_held"
    assert "you hold control" in r.json()["error"]["message"]
    r = await w.http.get("/client/control_requests", headers=ADMIN)
    assert r.json()["requests"] == []  # nothing for a manager to answer


async def test_an_unanswered_request_is_dropped_after_its_time(w: World) -> None:
    v = await w.vehicle()
    op = await w.person("operator", v)
    boss = await w.person("manager", v)
    assert (
        await w.client_post("request_control", op.headers, instance_id=v.instance_id)
    ).is_success

    async def pending() -> list[Any]:
        r = await w.http.get("/client/control_requests", headers=boss.headers)
        requests: list[Any] = r.json()["requests"]
        return requests

    assert len(await pending()) == 1
    w.clock.advance(601)  # FLEET_CONTROL_REQUEST_TTL_S is 600 by default

    async def dropped() -> bool:
        return await pending() == []

    await eventually(dropped)  # the control sweeper, on its own beat
