"""The operator SDK (remote_client.sdk) on the app in process, and its live events on a server."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

import httpx
import pytest

from remote_client.sdk import FleetApiError, FleetClient
from server.settings import Settings
from tests.factories import ADMIN_TOKEN, make_user, make_vehicle, sample, start_instance
from tests.live import serve

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


def _token(headers: dict[str, str]) -> str:
    return headers["Authorization"].removeprefix("Bearer ")


async def test_missions_and_control_through_the_sdk(client: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    _, op = await make_user(client, "operator", vehicles=[vid], username="ines")
    admin = FleetClient("http://test", ADMIN_TOKEN, client=client)
    ines = FleetClient("http://test", _token(op), client=client)

    assert [v["vehicle_id"] for v in (await ines.vehicles())["vehicles"]] == [vid]
    with pytest.raises(FleetApiError) as refused:
        await ines.go_to(iid, 43.95, 15.45)
    assert refused.value.status == 409 and refused.value.code == "control_not_held"
    assert refused.value.details[0]["instance_id"] == iid

    request = await ines.request_control(iid)
    pending = (await admin.control_requests(iid))["requests"]
    assert [r["request_id"] for r in pending] == [request["request_id"]]
    assert (await admin.grant_control(iid, "ines", 600))["holder"] == "ines"

    went = (await ines.go_to(iid, -33.9, -15.4, speed_mps=2.0))["commands"][0]
    held = (await ines.keep_station([iid], radius_m=4.0))["commands"][0]
    path = await ines.follow_path(iid, [(43.941, 15.441), (43.942, 15.442)], speed_mps=1.0)
    listed = {c["command_id"]: c for c in (await ines.commands(iid))["commands"]}
    assert listed[went["command_id"]]["args"] == {"lat": -33.9, "lon": -15.4, "speed_mps": 2.0}
    assert listed[held["command_id"]]["args"] == {"radius_m": 4.0}  # no position: where it is
    path_id = path["commands"][0]["command_id"]
    assert listed[path_id]["args"]["waypoints"][0] == {"lat": 43.941, "lon": 15.441}
    assert (await ines.cancel(path_id))["status"] == "cancelled"

    assert await ines.release_control(iid) == {"ok": True}
    with pytest.raises(FleetApiError) as after:
        await ines.keep_station([iid])
    assert after.value.code == "control_not_held"
    stopped = await ines.stop()  # stop needs no lease; no instance: every vehicle
    assert [c["instance_id"] for c in stopped["commands"]] == [iid]
    with pytest.raises(FleetApiError) as not_manager:
        await ines.revoke_control(iid)
    assert not_manager.value.status == 403


async def test_telemetry_pages_cover_every_sample_once(client: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    body = {"instance_id": iid, "samples": [sample(seq) for seq in range(1, 24)]}
    assert (await client.post("/upper/update_param", headers=vh, json=body)).is_success
    fleet = FleetClient("http://test", ADMIN_TOKEN, client=client)
    pages = [page async for page in fleet.telemetry_pages(vid, page=10)]
    assert [len(p) for p in pages] == [10, 10, 3]
    assert [s["seq"] for p in pages for s in p] == list(range(1, 24))
    with pytest.raises(FleetApiError) as unknown:
        _ = [page async for page in fleet.telemetry_pages("no-such-vehicle")]
    assert unknown.value.status == 404


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
