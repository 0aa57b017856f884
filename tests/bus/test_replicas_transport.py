"""A vehicle whose socket on one replica went quiet and that takes its instance up over
HTTP on the other (as test_replicas_shared_store: two apps, one store, a real
redis-server): the old socket stops taking its commands, which reach the long poll."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import pytest

from server.settings import Settings
from tests.bus.conftest import RedisServer
from tests.bus.test_replicas_shared_store import two_replicas
from tests.factories import make_user, make_vehicle
from tests.live import call, connect
from tests.server.test_ws_vehicle import CAPS, _close_code, token_of

pytestmark = pytest.mark.usefixtures("store_backend")


async def test_a_start_over_http_on_one_replica_frees_the_socket_on_the_other(
    make_settings: Callable[..., Settings], redis_server: RedisServer
) -> None:
    async with two_replicas(make_settings, redis_server) as (api_a, api_b, base_b):
        vid, vh = await make_vehicle(api_a)
        _, op = await make_user(api_a, "operator", [vid])
        async with await connect(base_b, "/ws/vehicle", token_of(vh)) as ws:
            started = await call(ws, "start_instance", "s", vehicle_id=vid, capabilities=CAPS)
            iid = started["instance_id"]
            body = {"vehicle_id": vid, "capabilities": CAPS}
            assert (await api_a.post("/upper/start_instance", headers=vh, json=body)).is_success
            assert await _close_code(ws) == 4409
            params = {"instance_id": iid, "wait_s": 20}
            poll = asyncio.create_task(
                api_a.get("/upper/get_control", headers=vh, params=params, timeout=30)
            )
            stop = {"instance_ids": [iid], "command": {"type": "stop", "args": {}}}
            r = await api_b.post("/client/submit_control", headers=op, json=stop)
            assert r.status_code == 202, r.text
            async with asyncio.timeout(8):
                answer = (await poll).json()
            assert [cmd["type"] for cmd in answer["commands"]] == ["stop"]
