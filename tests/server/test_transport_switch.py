"""A vehicle whose socket went quiet and that calls over HTTP now (an agent that fell
back to the long poll while its old socket is half-open): its commands come to the long
poll at once, and the old socket, which nobody reads, is closed (4409) rather than fed
every command and redelivery."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import httpx
import pytest

from server.settings import Settings
from tests.factories import ADMIN, make_user, make_vehicle
from tests.live import call, connect, recv_until, serve
from tests.server.test_ws_vehicle import CAPS, _close_code, token_of

pytestmark = pytest.mark.usefixtures("store_backend")


async def test_a_stop_reaches_the_long_poll_of_a_vehicle_whose_socket_went_quiet(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base, timeout=30) as c:
        vid, vh = await make_vehicle(c)
        _, op = await make_user(c, "operator", [vid])
        async with await connect(base, "/ws/vehicle", token_of(vh)) as ws:
            started = await call(ws, "start_instance", "s", vehicle_id=vid, capabilities=CAPS)
            iid = started["instance_id"]
            # The agent gives up on the socket (it reads nothing from it any more) and
            # takes the instance up again over HTTP, then long-polls.
            body = {"vehicle_id": vid, "capabilities": CAPS}
            again = await c.post("/upper/start_instance", headers=vh, json=body)
            assert again.json()["resumed"] is True, again.text
            assert again.json()["instance_id"] == iid
            params = {"instance_id": iid, "wait_s": 20}
            poll = asyncio.create_task(c.get("/upper/get_control", headers=vh, params=params))
            stop = {"instance_ids": [iid], "command": {"type": "stop", "args": {}}}
            r = await c.post("/client/submit_control", headers=op, json=stop)
            assert r.status_code == 202, r.text
            async with asyncio.timeout(5):  # not one ack timeout (10 s) later, nor 60 s
                answer = (await poll).json()
            assert [cmd["type"] for cmd in answer["commands"]] == ["stop"]
            assert await _close_code(ws) == 4409
            assert "HTTP" in str(ws.close_reason)


async def test_another_vehicle_s_long_poll_leaves_a_socket_alone(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base, timeout=30) as c:
        vid, vh = await make_vehicle(c)
        _, other = await make_vehicle(c)
        async with await connect(base, "/ws/vehicle", token_of(vh)) as ws:
            started = await call(ws, "start_instance", "s", vehicle_id=vid, capabilities=CAPS)
            params = {"instance_id": started["instance_id"], "wait_s": 0}
            r = await c.get("/upper/get_control", headers=other, params=params)
            assert r.status_code == 404, r.text
            assert (await call(ws, "heartbeat", "h", instance_id=started["instance_id"]))["ok"]
            await ws.send('{"op": "whoami", "id": "w"}')
            assert (await recv_until(ws, lambda f: f.get("id") == "w"))["ok"] is True


async def test_a_gateway_s_heartbeat_does_not_take_a_vehicle_from_its_own_socket(
    make_settings: Callable[..., Settings],
) -> None:
    """A vehicle reachable both through its gateway and on its own socket: the newer (its
    own) serves it; the gateway's routine heartbeat for it used to take it back, closing
    the vehicle's socket (4409), and the two took it from each other at every beat."""
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base, timeout=30) as c:
        vid, vh = await make_vehicle(c)
        _, op = await make_user(c, "operator", [vid])
        made = await c.post(
            "/api/gateways", headers=ADMIN, json={"gateway_id": "gw-both", "vehicles": [vid]}
        )
        assert made.status_code == 201, made.text
        async with await connect(base, "/ws/vehicle", made.json()["token"]) as gw:
            started = await call(gw, "start_instance", "g", vehicle_id=vid, capabilities=CAPS)
            iid = started["instance_id"]
            async with await connect(base, "/ws/vehicle", token_of(vh)) as own:
                again = await call(own, "start_instance", "s", vehicle_id=vid, capabilities=CAPS)
                assert again["instance_id"] == iid
                beat = await call(gw, "heartbeat", "h", vehicle_id=vid, instance_id=iid)
                assert beat["ok"] is True, beat
                stop = {"instance_ids": [iid], "command": {"type": "stop", "args": {}}}
                r = await c.post("/client/submit_control", headers=op, json=stop)
                assert r.status_code == 202, r.text
                pushed = await recv_until(own, lambda f: f.get("op") == "command")
                assert pushed["type"] == "stop"  # the vehicle's own socket still serves it
