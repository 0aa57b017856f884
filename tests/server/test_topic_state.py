"""A unit's topic has a current state too: its latest message, sent first to a new
subscriber (``snapshot: true``), as the server's own topics' are (API.md: on
subscribe, the current state of each topic comes first). A late subscriber to a
sonar's settings used to get nothing until the next publish."""

from __future__ import annotations

import httpx

from tests.factories import make_user, make_vehicle
from tests.live import call, connect, recv_until


def tok(headers: dict[str, str]) -> str:
    return headers["Authorization"].removeprefix("Bearer ")


async def test_a_late_subscriber_gets_the_topics_latest_message_first(
    base: str, api: httpx.AsyncClient
) -> None:
    vid, vh = await make_vehicle(api)
    _, ah = await make_user(api, "viewer", [vid])
    topic = f"vehicle/{vid}/sss_config"
    async with await connect(base, "/ws/vehicle", tok(vh)) as sonar:
        for n, range_m in enumerate((50, 75)):
            said = await call(sonar, "publish", f"p{n}", topic=topic, data={"range_m": range_m})
            assert said["ok"] is True
        async with await connect(base, "/ws/client", tok(ah)) as late:
            assert (await call(late, "subscribe", "s", topics=[topic]))["ok"] is True
            first = await recv_until(late, lambda f: f["op"] == "event")
            assert (first["data"], first.get("snapshot")) == ({"range_m": 75}, True)
            assert first["source"] == f"vehicle:{vid}" and "origin" not in first
            assert (await call(sonar, "publish", "p2", topic=topic, data={"range_m": 100}))["ok"]
            then = await recv_until(late, lambda f: f["op"] == "event")
            assert (then["data"], then.get("snapshot")) == ({"range_m": 100}, None)


async def test_a_message_too_large_to_keep_leaves_no_older_state_behind(
    base: str, api: httpx.AsyncClient
) -> None:
    """Past 64 KiB a message is not kept, and the one before it is no longer the latest."""
    vid, vh = await make_vehicle(api)
    _, ah = await make_user(api, "viewer", [vid])
    topic = f"vehicle/{vid}/scan"
    async with await connect(base, "/ws/vehicle", tok(vh)) as car:
        assert (await call(car, "publish", "small", topic=topic, data={"n": 1}))["ok"]
        big = {"n": 2, "line": "x" * 70_000}
        assert (await call(car, "publish", "big", topic=topic, data=big))["ok"]
        async with await connect(base, "/ws/client", tok(ah)) as late:
            assert (await call(late, "subscribe", "s", topics=[topic]))["ok"] is True
            assert (await call(car, "publish", "next", topic=topic, data={"n": 3}))["ok"]
            first = await recv_until(late, lambda f: f["op"] == "event")
            assert (first["data"], first.get("snapshot")) == ({"n": 3}, None)
