"""The operator SDK's live events (remote_client.sdk_live) on a real server: each topic's
state then its changes, refusals raised, and the largest message the server sends."""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import Callable
from typing import Any

import httpx
import pytest

from fleet_protocol.links import MAX_TEXT_FRAME_BYTES
from remote_client.sdk import FleetApiError, FleetClient
from server.settings import Settings
from tests.factories import ADMIN_TOKEN, make_user, make_vehicle, sample, start_instance
from tests.live import serve

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


def _token(headers: dict[str, str]) -> str:
    return headers["Authorization"].removeprefix("Bearer ")


async def test_events_give_the_state_then_changes_and_refusals_raise(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base:
        async with httpx.AsyncClient(base_url=base) as c:
            vid, vh = await make_vehicle(c)
            iid = (await start_instance(c, vid, vh))["instance_id"]
            first = {"instance_id": iid, "samples": [sample(1)]}
            assert (await c.post("/upper/update_param", headers=vh, json=first)).is_success
            seen: list[dict[str, Any]] = []
            async with FleetClient(base, ADMIN_TOKEN) as fleet:
                events = fleet.events([f"vehicle/{vid}/telemetry"])
                async with asyncio.timeout(20):
                    async for push in events:
                        seen.append(push)
                        if len(seen) == 3:
                            break
                        # the next sample, once the previous one was seen
                        body = {"instance_id": iid, "samples": [sample(len(seen) + 1)]}
                        response = await c.post("/upper/update_param", headers=vh, json=body)
                        assert response.is_success
                await events.aclose()
            assert [p.get("snapshot") for p in seen] == [True, None, None]
            assert [p["data"]["seq"] for p in seen] == [1, 2, 3]  # the latest first, then each

            _, viewer = await make_user(c, "viewer", vehicles=[])
            async with FleetClient(base, _token(viewer)) as blind:
                with pytest.raises(FleetApiError) as forbidden:
                    _ = [p async for p in blind.events([f"vehicle/{vid}/telemetry"])]
            assert forbidden.value.code == "forbidden"
            async with FleetClient(base, "fct_not-a-token-0000000000000000") as nobody:
                with pytest.raises(FleetApiError) as unknown:
                    _ = [p async for p in nobody.events(["fleet"])]
            assert unknown.value.status == 401
            async with FleetClient(base, ADMIN_TOKEN) as fleet:
                with pytest.raises(FleetApiError) as bad:
                    _ = [p async for p in fleet.events(["Not A Topic"])]
            assert bad.value.status == 422 and bad.value.code == "invalid"


async def test_events_take_the_largest_message_the_server_accepts(
    make_settings: Callable[..., Settings],
) -> None:
    """A publish of the full 1 MiB frame comes out as a larger event (its source and
    time added): the SDK's socket used to refuse it and end the iteration (fleetctl
    watch: "link lost"), the message lost."""
    async with serve(make_settings()) as base:
        async with httpx.AsyncClient(base_url=base) as c:
            name, headers = await make_user(c, "operator", vehicles=[])
        topic = f"user/{name}/big"
        op = {"op": "publish", "id": "publish", "topic": topic, "data": ""}
        big = "x" * (MAX_TEXT_FRAME_BYTES - len(json.dumps(op)))
        received: asyncio.Queue[dict[str, Any]] = asyncio.Queue()
        async with (
            FleetClient(base, _token(headers)) as fleet,
            FleetClient(base, ADMIN_TOKEN) as admin,
        ):

            async def listen() -> None:  # an admin reads under every user's name
                async for push in admin.events([topic]):
                    await received.put(push)

            listening = asyncio.create_task(listen())
            try:
                async with asyncio.timeout(20):
                    while received.empty():  # until the subscription is in place
                        await fleet.publish(topic, "ping")
                        with contextlib.suppress(TimeoutError):
                            await received.put(await asyncio.wait_for(received.get(), 0.2))
                    await fleet.publish(topic, big)
                    while (push := await received.get())["data"] != big:
                        assert push["data"] == "ping", push
            finally:
                listening.cancel()


async def test_events_go_on_when_the_user_s_rights_change(
    make_settings: Callable[..., Settings],
) -> None:
    """The server closes a user's sockets with 4012 (connect again) when an admin changes
    the user's vehicles: the iterator opens its socket again and gives the topics' state
    under the new rights, rather than ending as if the link were lost."""
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        one, oh = await make_vehicle(c)
        two, th = await make_vehicle(c)
        for vid, vh in ((one, oh), (two, th)):
            await start_instance(c, vid, vh)
        name, headers = await make_user(c, "viewer", vehicles=[one])
        admin = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
        seen: list[set[str]] = []
        async with FleetClient(base, _token(headers)) as fleet:
            events = fleet.events(["fleet"])
            async with asyncio.timeout(20):
                async for push in events:
                    if not push.get("snapshot"):
                        continue  # a presence change: not what is looked at here
                    seen.append({v["vehicle_id"] for v in push["data"]["vehicles"]})
                    if len(seen) == 2:
                        break
                    patch = {"vehicles": [one, two]}
                    r = await c.patch(f"/api/users/{name}", headers=admin, json=patch)
                    assert r.status_code == 200, r.text
            await events.aclose()
        assert seen == [{one}, {one, two}]
