"""A unit with several sockets (an operator's console and fleetctl; a vehicle's own
socket beside its gateway's; the units behind one gateway): each socket's
subscriptions and registrations are its own. One socket closing or unsubscribing
used to take the whole unit out of the routing table, so a gateway stopped
forwarding up what the unit's other sockets still wanted (acknowledged ``ok``,
never delivered); one gateway unit's ``throttle_ms`` throttled the others."""

from __future__ import annotations

from typing import Any

import httpx
import pytest

from tests.factories import ADMIN, make_user, make_vehicle
from tests.live import call, connect, recv_until

pytestmark = pytest.mark.usefixtures("store_backend")


def tok(headers: dict[str, str]) -> str:
    return headers["Authorization"].removeprefix("Bearer ")


async def _gateway(api: httpx.AsyncClient, vehicles: list[str]) -> str:
    r = await api.post(
        "/api/gateways", headers=ADMIN, json={"gateway_id": "gw-socks", "vehicles": vehicles}
    )
    assert r.status_code == 201, r.text
    return str(r.json()["token"])


async def _routes(ws: Any, unit: str) -> dict[str, Any]:
    return await recv_until(ws, lambda f: f["op"] == "routes" and f["unit"] == unit)


async def test_one_of_a_users_sockets_closing_keeps_the_gateway_forwarding(
    base: str, api: httpx.AsyncClient
) -> None:
    vid, _ = await make_vehicle(api)
    gw = await _gateway(api, [vid])
    ana, ah = await make_user(api, "viewer", [vid])
    bob, bh = await make_user(api, "viewer", [vid])
    topic = f"vehicle/{vid}/sss_meta"
    async with await connect(base, "/ws/vehicle", gw) as g:
        assert (await call(g, "register", "r", topics=[topic], vehicle_id=vid))["ok"]
        async with await connect(base, "/ws/client", tok(ah)) as console:
            async with await connect(base, "/ws/client", tok(ah)) as watch:
                for ws in (console, watch):
                    assert (await call(ws, "subscribe", "s", topics=[topic]))["ok"]
                routes = await _routes(g, "gateway:gw-socks")
                assert routes["forward_up"] == [topic]
            # the second socket closed; the console still wants it: the table says so
            async with await connect(base, "/ws/client", tok(bh)) as other:
                assert (await call(other, "subscribe", "s", topics=[topic]))["ok"]
                mine = await recv_until(
                    g,
                    lambda f: (
                        f["op"] == "routes"
                        and f["unit"] == f"vehicle:{vid}"
                        and f"user:{bob}" in f["produces"].get(topic, [])
                    ),
                )
                assert mine["produces"][topic] == [f"user:{ana}", f"user:{bob}"]
                # and what the gateway sends up reaches the console
                published = await call(
                    g, "publish", "p", topic=topic, data={"n": 1}, vehicle_id=vid
                )
                assert published["ok"]
                event = await recv_until(console, lambda f: f["op"] == "event")
                assert event["data"] == {"n": 1}


async def test_unsubscribing_on_one_socket_leaves_the_users_other_socket_subscribed(
    base: str, api: httpx.AsyncClient
) -> None:
    vid, vh = await make_vehicle(api)
    ana, ah = await make_user(api, "viewer", [vid])
    bob, bh = await make_user(api, "viewer", [vid])
    topic = f"vehicle/{vid}/sss_meta"
    async with (
        await connect(base, "/ws/vehicle", tok(vh)) as car,
        await connect(base, "/ws/client", tok(ah)) as one,
        await connect(base, "/ws/client", tok(ah)) as two,
        await connect(base, "/ws/client", tok(bh)) as other,
    ):
        assert (await call(car, "register", "r", topics=[topic]))["ok"]
        for ws in (one, two):
            assert (await call(ws, "subscribe", "s", topics=[topic]))["ok"]
        assert (await call(one, "unsubscribe", "u", topics=[topic]))["ok"]
        assert (await call(other, "subscribe", "s", topics=[topic]))["ok"]
        routes = await recv_until(
            car,
            lambda f: f["op"] == "routes" and f"user:{bob}" in f["produces"].get(topic, []),
        )
        assert routes["produces"][topic] == [f"user:{ana}", f"user:{bob}"]
        # the last of ana's sockets to want it unsubscribes: she is out of the table
        assert (await call(two, "unsubscribe", "u", topics=[topic]))["ok"]
        routes = await recv_until(car, lambda f: f["op"] == "routes")
        assert routes["produces"][topic] == [f"user:{bob}"]


async def test_a_vehicles_own_socket_closing_keeps_what_its_gateway_registered(
    base: str, api: httpx.AsyncClient
) -> None:
    vid, vh = await make_vehicle(api)
    gw = await _gateway(api, [vid])
    ana, ah = await make_user(api, "viewer", [vid])
    bob, bh = await make_user(api, "viewer", [vid])
    topic = f"vehicle/{vid}/sss_meta"
    async with (
        await connect(base, "/ws/vehicle", gw) as g,
        await connect(base, "/ws/client", tok(ah)) as console,
        await connect(base, "/ws/client", tok(bh)) as other,
    ):
        assert (await call(g, "register", "r", topics=[topic], vehicle_id=vid))["ok"]
        assert (await call(console, "subscribe", "s", topics=[topic]))["ok"]
        await recv_until(g, lambda f: f["op"] == "routes" and f.get("forward_up") == [topic])
        async with await connect(base, "/ws/vehicle", tok(vh)) as own:
            assert (await call(own, "subscribe", "s", topics=[f"vehicle/{vid}/other"]))["ok"]
        # the vehicle's registration through its gateway is still in the table
        assert (await call(other, "subscribe", "s", topics=[topic]))["ok"]
        routes = await recv_until(
            g,
            lambda f: (
                f["op"] == "routes"
                and f["unit"] == f"vehicle:{vid}"
                and f"user:{bob}" in f["produces"].get(topic, [])
            ),
        )
        assert routes["produces"][topic] == [f"user:{ana}", f"user:{bob}"]


async def test_each_unit_on_a_gateway_socket_gets_what_it_asked_not_its_neighbours_throttle(
    base: str, api: httpx.AsyncClient
) -> None:
    vid, _ = await make_vehicle(api)
    gw = await _gateway(api, [vid])
    ana, ah = await make_user(api, "operator", [vid])
    topic = f"user/{ana}/advice/{vid}"
    async with (
        await connect(base, "/ws/vehicle", gw) as g,
        await connect(base, "/ws/client", tok(ah)) as console,
    ):
        assert (await call(g, "subscribe", "a", topics=[topic], vehicle_id=vid))["ok"]
        # the gateway's own unit asks for one a minute, on the same socket
        assert (await call(g, "subscribe", "b", topics=[topic], throttle_ms=60_000))["ok"]
        for n in range(20):
            assert (await call(console, "publish", f"p{n}", topic=topic, data={"n": n}))["ok"]
        got = []
        while len(got) < 20:  # every one: the vehicle's unit asked for no throttle
            event = await recv_until(g, lambda f: f["op"] == "event" and f["topic"] == topic)
            got.append(event["data"]["n"])
        assert got == list(range(20))


async def test_a_gateway_acting_for_one_vehicle_writes_under_that_vehicle_alone(
    base: str, api: httpx.AsyncClient
) -> None:
    """Acting for usv A (``vehicle_id``), a gateway's publish on B's topics was taken, sent
    out as A's (``source: vehicle:A``); A's own token, or a unit behind the gateway, is
    refused it."""
    a, _ = await make_vehicle(api)
    b, _ = await make_vehicle(api)
    gw = await _gateway(api, [a, b])
    async with await connect(base, "/ws/vehicle", gw) as g:
        for op, fields in (
            ("publish", {"topic": f"vehicle/{b}/status", "data": 1}),
            ("register", {"topics": [f"vehicle/{b}/status"]}),
            ("publish", {"topic": "gateway/gw-socks/status", "data": 1}),
        ):
            refused = await call(g, op, "x", vehicle_id=a, **fields)
            assert refused["ok"] is False and refused["error"]["code"] == "forbidden", refused
            assert f"acting for vehicle {a}" in refused["error"]["message"]
            assert refused["error"]["details"][0]["field"].startswith("topic")
        said = await call(g, "publish", "ok1", vehicle_id=a, topic=f"vehicle/{a}/status", data=2)
        assert said["ok"] is True, said
        # as itself (no vehicle named), the gateway writes for any of its vehicles
        said = await call(g, "publish", "ok2", topic=f"vehicle/{b}/status", data=3)
        assert said["ok"] is True, said


async def test_a_vehicle_a_token_does_not_act_for_is_named_in_the_refusal(
    base: str, api: httpx.AsyncClient
) -> None:
    """The refusal "this token does not act for vehicle X" named no field: the op's, or
    the body's, ``vehicle_id`` is the one to put right."""
    a, _ = await make_vehicle(api)
    other, _ = await make_vehicle(api)
    gw = await _gateway(api, [a])
    async with await connect(base, "/ws/vehicle", gw) as g:
        refused = await call(g, "subscribe", "s", vehicle_id=other, topics=[f"vehicle/{a}/x"])
        assert refused["ok"] is False and refused["error"]["code"] == "forbidden", refused
        assert [d["field"] for d in refused["error"]["details"]] == ["vehicle_id"]
    r = await api.post(
        "/upper/start_instance",
        headers={"Authorization": f"Bearer {gw}"},
        json={"vehicle_id": other},
    )
    assert r.status_code == 403, r.text
    assert [d["field"] for d in r.json()["error"]["details"]] == ["vehicle_id"]


async def test_a_unit_s_new_socket_is_told_the_unit_s_part(
    base: str, api: httpx.AsyncClient
) -> None:
    """A second socket of a unit (the console beside fleetctl) whose op changes nothing
    in the table is still told the unit's part (``routes``), as the first one was."""
    name, headers = await make_user(api, "operator", [])
    topic = f"user/{name}/plan"
    async with await connect(base, "/ws/client", tok(headers)) as first:
        assert (await call(first, "register", "r", topics=[topic]))["ok"]
        assert topic in (await _routes(first, f"user:{name}"))["produces"]
        async with await connect(base, "/ws/client", tok(headers)) as second:
            assert (await call(second, "register", "r", topics=[topic]))["ok"]  # no change
            assert topic in (await _routes(second, f"user:{name}"))["produces"]
