"""A vehicle's name put right on one replica while another keeps its instance."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

import httpx
import pytest

from server.settings import Settings
from tests.bus.conftest import RedisServer
from tests.bus.test_replicas_shared_store import two_replicas
from tests.factories import ADMIN, make_vehicle

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


async def _name(api: httpx.AsyncClient, vehicle_id: str) -> str:
    r = await api.get(f"/api/vehicles/{vehicle_id}", headers=ADMIN)
    assert r.status_code == 200, r.text
    return str(r.json()["name"])


async def _post(api: httpx.AsyncClient, path: str, headers: dict[str, str], **body: Any) -> Any:
    r = await api.post(path, headers=headers, json=body)
    assert r.status_code == 200, r.text
    return r.json()


async def test_a_name_changed_on_one_replica_holds_on_the_replica_of_the_vehicle(
    make_settings: Callable[..., Settings], redis_server: RedisServer
) -> None:
    # The vehicle's replica writes its instance back every 20 s: what it changed (its
    # parameters) waits in its copy while the name is changed on the other replica.
    slow = {"persist_interval_s": 20, "stale_after_s": 60, "offline_after_s": 120}
    async with two_replicas(make_settings, redis_server, **slow) as (api_a, api_b, _):
        vid, vehicle = await make_vehicle(api_a)
        iid = (await _post(api_b, "/upper/start_instance", vehicle, vehicle_id=vid))["instance_id"]
        await _post(api_b, "/upper/update_param", vehicle, instance_id=iid, params={"m": 1})

        r = await api_a.patch(f"/api/vehicles/{vid}", headers=ADMIN, json={"name": "Renamed"})
        assert r.status_code == 200 and r.json()["name"] == "Renamed", r.text
        async with asyncio.timeout(10):
            while await _name(api_b, vid) != "Renamed":  # noqa: ASYNC110 (deadline poll)
                await asyncio.sleep(0.05)

        # The vehicle's replica writes the instance (its end) with the name put right.
        await _post(api_b, "/upper/finish_instance", vehicle, instance_id=iid)
        await _post(api_a, "/upper/start_instance", vehicle, vehicle_id=vid)
        assert await _name(api_a, vid) == "Renamed"
        assert await _name(api_b, vid) == "Renamed"
