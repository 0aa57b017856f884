"""The event log read a page at a time: ``next_after`` and ``after`` (docs/api.md, Events)."""

from __future__ import annotations

from typing import Any

import httpx
import pytest

from tests.factories import ADMIN, FakeClock, make_vehicle, start_instance

pytestmark = pytest.mark.usefixtures("store_backend")


async def _instance_lives(client: httpx.AsyncClient, vid: str, vh: dict[str, str], n: int) -> None:
    """``n`` instances started and finished: two events each, at least."""
    for _ in range(n):
        iid = (await start_instance(client, vid, vh))["instance_id"]
        r = await client.post("/upper/finish_instance", headers=vh, json={"instance_id": iid})
        assert r.status_code == 200, r.text


async def _pages(
    client: httpx.AsyncClient, params: dict[str, Any], limit: int
) -> list[list[dict[str, Any]]]:
    pages: list[list[dict[str, Any]]] = []
    after = None
    while True:
        query = {**params, "limit": limit} | ({"after": after} if after else {})
        r = await client.get("/api/events", headers=ADMIN, params=query)
        assert r.status_code == 200, r.text
        body = r.json()
        pages.append(body["events"])
        after = body["next_after"]
        if after is None:
            return pages
        assert len(body["events"]) == limit  # only a full page has a next one
        assert len(pages) < 100, "the pages never end"


async def test_pages_of_events_that_share_one_millisecond_give_each_once_in_order(
    clocked_client: httpx.AsyncClient, clock: FakeClock
) -> None:
    client = clocked_client  # its clock stands still: every event has the same time
    vid, vh = await make_vehicle(client)
    await _instance_lives(client, vid, vh, 6)
    whole = (
        await client.get("/api/events", headers=ADMIN, params={"vehicle_id": vid, "limit": 10_000})
    ).json()
    assert whole["next_after"] is None
    events = whole["events"]
    assert len(events) >= 12 and len({e["at"] for e in events}) == 1
    # In the order they happened, though they share one time.
    lives = [e["data"]["action"] for e in events if e["kind"] == "instance"]
    assert lives == ["started", "finished"] * 6

    for limit in (1, 5, len(events)):
        pages = await _pages(client, {"vehicle_id": vid}, limit)
        assert [e for page in pages for e in page] == events, limit
    assert pages[0] == events and len(pages) == 2 and pages[1] == []

    # Events recorded after a page was read come on the next one.
    first = (
        await client.get("/api/events", headers=ADMIN, params={"vehicle_id": vid, "limit": 3})
    ).json()
    clock.advance(1)
    await _instance_lives(client, vid, vh, 1)
    rest = await _pages(client, {"vehicle_id": vid}, 1000)
    r = await client.get(
        "/api/events",
        headers=ADMIN,
        params={"vehicle_id": vid, "after": first["next_after"]},
    )
    later = r.json()["events"]
    assert first["events"] + later == rest[0]
    assert len(later) >= len(events) - 3 + 2


async def test_a_page_after_a_cursor_keeps_the_querys_filters(
    clocked_client: httpx.AsyncClient, clock: FakeClock
) -> None:
    client = clocked_client
    one, one_h = await make_vehicle(client)
    two, two_h = await make_vehicle(client)
    for _ in range(3):
        await _instance_lives(client, one, one_h, 1)
        await _instance_lives(client, two, two_h, 1)
        clock.advance(0.001)
    pages = await _pages(client, {"vehicle_id": two, "kind": "instance"}, 2)
    got = [e for page in pages for e in page]
    assert len(got) == 6 and {(e["vehicle_id"], e["kind"]) for e in got} == {(two, "instance")}
    assert [e["at"] for e in got] == sorted(e["at"] for e in got)


@pytest.mark.parametrize(
    "after",
    [
        "",
        "abc",
        "not-a-time_" + "0" * 24,
        "2026-13-01T00:00:00.000Z_" + "0" * 24,
        "2026-01-01T00:00:00.000Z_" + "0" * 23,
        "2026-01-01T00:00:00.000Z_" + "g" * 24,
        "x" * 129,
        # out of the range every time of the API has (1970 to 2100), and out of Python's
        # once put in UTC (a 500 before)
        "0001-01-01T00:00:00+01:00_" + "a" * 24,
        "9999-12-31T23:59:59-01:00_" + "a" * 24,
        "0001-01-01T00:00:00Z_" + "a" * 24,
        "2100-01-01T00:00:00.001Z_" + "a" * 24,
    ],
)
async def test_a_cursor_the_server_did_not_give_is_422_naming_after(
    client: httpx.AsyncClient, after: str
) -> None:
    r = await client.get("/api/events", headers=ADMIN, params={"after": after})
    assert r.status_code == 422, r.text
    body = r.json()["error"]
    assert "after" in body["message"] or "after" in str(body["details"]), body


async def test_a_cursor_outlives_its_event(client: httpx.AsyncClient) -> None:
    """A cursor names a time and an id, not a stored event: one whose event is gone (the
    retention dropped it) still gives what came after."""
    vid, vh = await make_vehicle(client)
    await start_instance(client, vid, vh)
    r = await client.get(
        "/api/events",
        headers=ADMIN,
        params={"vehicle_id": vid, "after": "2026-01-01T00:00:00.000Z_" + "0" * 24},
    )
    assert r.status_code == 200, r.text
    assert any(e["kind"] == "instance" for e in r.json()["events"])


async def test_a_client_following_the_log_keeps_the_cursor_of_the_last_page(
    client: httpx.AsyncClient,
) -> None:
    """``cursor`` is on every page with an event, full or not: after it, only what came since."""
    vid, vh = await make_vehicle(client)
    await _instance_lives(client, vid, vh, 1)
    r = await client.get("/api/events", headers=ADMIN, params={"vehicle_id": vid})
    first = r.json()
    assert first["events"] and first["next_after"] is None and first["cursor"]
    r = await client.get(
        "/api/events", headers=ADMIN, params={"vehicle_id": vid, "after": first["cursor"]}
    )
    assert r.json() == {"events": [], "next_after": None, "cursor": None}
    await _instance_lives(client, vid, vh, 1)
    r = await client.get(
        "/api/events", headers=ADMIN, params={"vehicle_id": vid, "after": first["cursor"]}
    )
    since = r.json()["events"]
    assert [e["data"].get("action") for e in since if e["kind"] == "instance"] == [
        "started", "finished",
    ]  # fmt: skip
    assert not {e["event_id"] for e in since} & {e["event_id"] for e in first["events"]}
