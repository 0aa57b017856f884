"""What a gateway's local units are told when the server refuses the gateway something: its
token (revoked), or a subscription it holds for them (a vehicle it does not act for, a
gateway's topics it may not read). A real server in this process, as in
test_gateway_media; the refused token through ``run_agents``, as ``fleet-agent gateway``
runs it."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import pytest
import websockets
from pydantic import SecretStr

from fleet_protocol.links import CLOSE_UNAUTHORIZED
from server.domain.access import Principal
from server.domain.topics import read_refusal as server_read_refusal
from server.settings import Settings
from tests.agent.test_gateway_media import Frame, World, ack, event_on, gateway, next_json
from tests.factories import ADMIN, make_vehicle, unique
from tests.live import free_port, serve
from vehicle_client.config import LinkOptions, VehicleOptions
from vehicle_client.gateway.forwarding import read_refusal
from vehicle_client.runner import run_agents

DOWN = "ws://127.0.0.1:1/ws/vehicle"  # the cloud out of reach


def error_on(topic: str) -> Callable[[Frame], bool]:
    """An ``error`` push naming ``topic`` in its details, as the server names a topic."""
    return lambda f: (
        f["op"] == "error"
        and any(
            (d["field"] == "topic" or d["field"].startswith("topics."))
            and d["message"].startswith(f"{topic}: ")
            for d in f["error"].get("details") or []
        )
    )


async def outsiders(w: World) -> tuple[str, str]:
    """A vehicle the gateway does not act for, and another gateway that does (whose
    topics the first may not read)."""
    async with httpx.AsyncClient(base_url=w.base, timeout=10) as api:
        stranger, _ = await make_vehicle(api)
        other = unique("gw")
        body = {"gateway_id": other, "vehicles": [stranger]}
        r = await api.post("/api/gateways", headers=ADMIN, json=body)
        assert r.status_code == 201, r.text
    return stranger, other


async def connected_unit(port: int, vehicle_id: str, within_s: float = 20) -> Any:
    """A unit's connection to a gateway whose port opens once it has started."""
    url = f"ws://127.0.0.1:{port}/?vehicle_id={vehicle_id}"
    async with asyncio.timeout(within_s):
        while True:
            try:
                return await websockets.connect(url, compression=None)
            except OSError:
                await asyncio.sleep(0.05)


async def test_a_gateway_whose_token_is_revoked_closes_its_units_with_4401_and_why(
    make_settings: Callable[..., Settings], tmp_path: Path
) -> None:
    """The server closes the gateway's link with 4401 and the gateway stops (fatal): its
    units used to see 1001 with no reason, as at a restart, and could not tell."""
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base, timeout=10) as api:
        a, _ = await make_vehicle(api)
        gw = unique("gw")
        r = await api.post("/api/gateways", headers=ADMIN, json={"gateway_id": gw, "vehicles": [a]})
        assert r.status_code == 201, r.text
        link = LinkOptions(server=base, token=SecretStr(r.json()["token"]), transport="ws")
        port = free_port()
        vehicles = [(VehicleOptions(vehicle_id=a), tmp_path / "a.db")]
        running = asyncio.create_task(run_agents(link, vehicles, listen=f"127.0.0.1:{port}"))
        try:
            unit = await connected_unit(port, a)
            subscribed = await ack(unit, "subscribe", "s", topics=[f"vehicle/{a}/status"])
            assert subscribed["ok"] is True and "local_only" not in subscribed, subscribed
            revoked = await api.post(f"/api/gateways/{gw}/revoke_tokens", headers=ADMIN)
            assert revoked.status_code == 200, revoked.text
            with pytest.raises(websockets.ConnectionClosed):
                await next_json(unit, lambda f: False, within_s=20)
            assert unit.close_code == CLOSE_UNAUTHORIZED
            assert "token was refused" in (unit.close_reason or ""), unit.close_reason
            async with asyncio.timeout(20):
                assert await running == 2  # the agents' refusal: fatal, as before
        finally:
            running.cancel()
            await asyncio.gather(running, return_exceptions=True)


async def test_a_unit_may_not_subscribe_to_a_vehicle_the_gateway_does_not_act_for(
    make_settings: Callable[..., Settings],
) -> None:
    """Refused here (forbidden, the topic named) once the server said whom the gateway
    acts for, the link down too: it used to be acked ``local_only`` and refused above at
    the replay, its unit never told."""
    async with gateway(make_settings) as w:
        stranger, _ = await outsiders(w)
        theirs = f"vehicle/{stranger}/telemetry"
        async with w.unit(w.a) as ua:
            assert (await ack(ua, "subscribe", "warm", topics=[f"vehicle/{w.b}/x"]))["ok"]
            w.units.link.url = DOWN
            await w.units.link.aclose()
            refused = await ack(ua, "subscribe", "s", topics=[f"vehicle/{w.b}/y", theirs])
            assert refused["ok"] is False and refused["error"]["code"] == "forbidden", refused
            assert refused["error"]["details"][0]["message"].startswith(f"{theirs}: ")
            held = w.units.router.held(w.a).consumes
            assert theirs not in held and f"vehicle/{w.b}/y" not in held  # the op, whole


async def test_a_topic_of_no_known_shape_is_invalid_at_the_gateway_as_at_the_server(
    make_settings: Callable[..., Settings],
) -> None:
    """A unit's subscribe, register or publish naming a topic nobody may read or write
    (no such namespace, a namespace's bare owner) is ``invalid`` with the field named,
    the link down too: it was acked ``local_only`` or refused ``forbidden`` here, where
    the server says ``invalid``."""
    async with gateway(make_settings) as w, w.unit(w.a) as ua:
        w.units.link.url = DOWN
        await w.units.link.aclose()
        ops = [
            ("subscribe", {"topics": [f"vehicle/{w.b}/y", "weather/x/y"]}, "topics.1"),
            ("register", {"topics": [f"vehicle/{w.a}/z", f"vehicle/{w.a}"]}, "topics.1"),
            ("publish", {"topic": "gateway/gw", "data": {}}, "topic"),
        ]
        for index, (op, fields, field) in enumerate(ops):
            bad = fields["topics"][1] if "topics" in fields else fields["topic"]
            refused = await ack(ua, op, f"o{index}", **fields)
            assert refused["ok"] is False and refused["error"]["code"] == "invalid", refused
            assert refused["error"]["details"] == [
                {"field": field, "message": refused["error"]["message"]}
            ], refused
            assert refused["error"]["message"].startswith(f"{bad}: "), refused
        assert f"vehicle/{w.b}/y" not in w.units.router.held(w.a).consumes  # the op, whole


async def test_subscriptions_refused_as_the_link_comes_back_are_told_and_let_go_of(
    make_settings: Callable[..., Settings],
) -> None:
    """Taken while the link was down (``local_only``, the vehicles not known yet): one of
    a vehicle the gateway does not act for, one of a gateway it may not read. As the link
    comes back, the unit gets an ``error`` naming each, they are not held (so not sent
    again at the next reconnection), and what it may read still comes: the server
    refuses an op whole, and all three went up in one."""
    async with gateway(make_settings) as w:
        stranger, other = await outsiders(w)
        vehicle_s, gateway_s = f"vehicle/{stranger}/telemetry", f"gateway/{other}/status"
        note = f"user/{w.operator}/plan/{w.a}"
        base_url, w.units.link.url = w.units.link.url, DOWN
        async with w.unit(w.a) as ua, await w.operator_ws() as op:
            taken = await ack(ua, "subscribe", "s", topics=[vehicle_s, gateway_s, note])
            assert (taken["ok"], taken.get("local_only")) == (True, True), taken
            w.units.link.url = base_url
            await w.units.link.open()  # whoami, then the replay
            told = [await next_json(ua, error_on(t)) for t in (vehicle_s, gateway_s)]
            assert [e["error"]["code"] for e in told] == ["forbidden", "forbidden"]
            assert set(w.units.router.held(w.a).consumes) == {note}
            replayed = [t for sent in w.units.router.replay() for t in sent["topics"]]
            assert vehicle_s not in replayed and gateway_s not in replayed
            assert (await ack(op, "publish", "p", topic=note, data={"go": 1}))["ok"] is True
            assert (await next_json(ua, event_on(note)))["data"] == {"go": 1}


async def test_a_subscribe_without_an_id_refused_above_is_told_with_an_error(
    make_settings: Callable[..., Settings],
) -> None:
    """As the server answers an op without an ``id``: an ``error`` push. The gateway
    relayed only acks, and a refusal without one went nowhere."""
    async with gateway(make_settings) as w:
        _, other = await outsiders(w)
        topic = f"gateway/{other}/status"
        async with w.unit(w.a) as ua:
            assert (await ack(ua, "subscribe", "warm", topics=[f"vehicle/{w.a}/x"]))["ok"]
            await ua.send(json.dumps({"op": "subscribe", "topics": [topic]}))
            told = await next_json(ua, error_on(topic))
            assert told["error"]["code"] == "forbidden", told


TOPICS = [
    "fleet",
    "zones",
    "vehicle/usv-1/telemetry",
    "vehicle/usv-1/camera/front",
    "vehicle/usv-9/telemetry",
    "vehicle/usv-9/sonar/meta",
    "user/ana/plan",
    "user/ana/plan/usv-1",
    "user/ana/plan/usv-1/more",
    "user/ana/plan/usv-9",
]


@pytest.mark.parametrize("topic", TOPICS)
def test_the_gateway_s_read_rule_is_the_server_s_for_a_gateway(topic: str) -> None:
    """What the gateway refuses, the server refuses a gateway token listing the same
    vehicles; what the gateway lets up, the server takes (``gateway/`` topics, which
    depend on another gateway's vehicles, are the server's alone to judge)."""
    acts_for = frozenset({"usv-1", "usv-2"})
    principal = Principal(kind="gateway", name="gw-1", vehicles=acts_for)
    here = read_refusal(topic, acts_for) is None
    assert here == (server_read_refusal(principal, topic) is None), topic
    assert read_refusal(topic, None) is None or topic in ("fleet", "zones", "user/ana/plan")
