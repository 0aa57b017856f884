"""Several local units acting for one vehicle behind a gateway (a sonar driver, a camera, a
mission script), each its own connection: what each gets, and what the server above is
told for their vehicle, which it knows once (a real server in this process, as in
test_gateway_media). What the server holds is read off the operator's ``routes`` push:
the consumers of a topic the operator registered."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Callable
from typing import Any

import pytest
import websockets

from fleet_protocol.links import CLOSE_FORBIDDEN, CLOSE_REPLACED
from fleet_protocol.ws import RoutesPush
from server.settings import Settings
from tests.agent.test_gateway_media import (
    Frame,
    World,
    ack,
    event_on,
    gateway,
    media,
    next_json,
    next_media,
)
from tests.server.commanding import eventually
from vehicle_client.gateway.unit_admission import CLOSE_BAD_REQUEST


def consumers(w: World, topic: str, want: Callable[[list[str]], bool]) -> Callable[[Frame], bool]:
    """The operator's ``routes`` push once the units consuming ``topic`` are as ``want``."""
    return lambda f: (
        f["op"] == "routes"
        and f["unit"] == f"user:{w.operator}"
        and topic in f["produces"]
        and want(f["produces"][topic])
    )


async def units_of(w: World, vehicle_id: str, count: int) -> None:
    """Until the gateway has seen the units that closed leave."""

    async def left() -> bool:
        return len(w.units.router.of_vehicle(vehicle_id)) == count

    await eventually(left)


async def events_until(ws: Any, topic: str, last: Any) -> list[Any]:
    """The data of the events on ``topic`` up to the one holding ``last``."""
    got: list[Any] = []
    while last not in got:
        got.append((await next_json(ws, event_on(topic)))["data"])
    return got


async def closed_with(ws: Any) -> Any:
    with pytest.raises(websockets.ConnectionClosed):
        await next_json(ws, lambda f: False)
    return ws.close_code


async def test_two_units_of_one_vehicle_each_get_what_they_subscribed(
    make_settings: Callable[..., Settings],
) -> None:
    """Both stay connected (the second used to replace the first, 4409); each gets what it
    asked for and not what the other did; one's publish reaches the other."""
    async with gateway(make_settings) as w:
        plan, goal = f"user/{w.operator}/plan/{w.a}", f"user/{w.operator}/goal/{w.a}"
        sonar = f"vehicle/{w.a}/sonar_meta"
        async with await w.operator_ws() as op, w.unit(w.a) as driver, w.unit(w.a) as script:
            assert (await ack(driver, "subscribe", "s", topics=[plan, sonar]))["ok"] is True
            assert (await ack(script, "subscribe", "s", topics=[goal, sonar]))["ok"] is True
            assert (await ack(op, "publish", "p1", topic=plan, data=1))["ok"] is True
            assert (await ack(op, "publish", "p2", topic=goal, data=2))["ok"] is True
            assert (await next_json(driver, event_on(plan)))["data"] == 1
            got = await next_json(script, lambda f: f["op"] == "event")
            assert (got["topic"], got["data"]) == (goal, 2)  # not plan: it did not ask
            # the driver's publish reaches the script beside it, not the driver itself
            assert (await ack(driver, "publish", "p3", topic=sonar, data=3))["ok"] is True
            assert (await next_json(script, event_on(sonar)))["data"] == 3
            assert (await ack(op, "publish", "p4", topic=plan, data=4))["ok"] is True
            got = await next_json(driver, lambda f: f["op"] == "event")
            assert (got["topic"], got["data"]) == (plan, 4)


async def test_a_unit_s_media_frames_reach_the_unit_of_its_vehicle_that_subscribed(
    make_settings: Callable[..., Settings],
) -> None:
    async with gateway(make_settings) as w:
        cam = f"vehicle/{w.a}/camera/front"
        async with w.unit(w.a, "camera") as camera, w.unit(w.a, "tracker") as tracker:
            assert (await ack(tracker, "subscribe", "s", topics=[cam]))["ok"] is True
            await camera.send(media(cam, b"frame-1"))
            assert await next_media(tracker, cam) == b"frame-1"


async def test_one_unit_letting_go_leaves_the_others_served_and_the_last_takes_it_back_above(
    make_settings: Callable[..., Settings],
) -> None:
    """The vehicle holds a topic above for as long as one of its units does: one
    unsubscribing or leaving does not cut the others off; the last one letting go takes
    it back above (the server's table no longer lists the vehicle as a consumer)."""
    async with gateway(make_settings) as w:
        plan = f"user/{w.operator}/plan/{w.a}"
        vehicle = f"vehicle:{w.a}"
        async with (
            await w.operator_ws() as op,
            w.unit(w.a) as first,
            w.unit(w.a) as second,
            w.unit(w.a) as third,
        ):
            assert (await ack(op, "register", "r", topics=[plan]))["ok"] is True
            for n, unit in enumerate((first, second, third)):
                assert (await ack(unit, "subscribe", f"s{n}", topics=[plan]))["ok"] is True
            await next_json(op, consumers(w, plan, lambda units: vehicle in units))

            assert (await ack(first, "unsubscribe", "u", topics=[plan]))["ok"] is True
            assert (await ack(op, "publish", "p1", topic=plan, data=1))["ok"] is True
            for unit in (second, third):
                assert (await next_json(unit, event_on(plan)))["data"] == 1

            await second.close()
            await units_of(w, w.a, 2)
            assert (await ack(op, "publish", "p2", topic=plan, data=2))["ok"] is True
            assert (await next_json(third, event_on(plan)))["data"] == 2

            assert (await ack(third, "unsubscribe", "u", topics=[plan]))["ok"] is True
            await next_json(op, consumers(w, plan, lambda units: vehicle not in units))


async def test_a_unit_that_asks_for_every_event_gets_each_beside_a_throttled_sibling(
    make_settings: Callable[..., Settings],
) -> None:
    """The gateway's socket is served a topic at the least ``throttle_ms`` its vehicle's
    units asked: a sibling asking less often first does not throttle the other."""
    async with gateway(make_settings) as w:
        plan = f"user/{w.operator}/plan/{w.a}"
        async with await w.operator_ws() as op, w.unit(w.a) as slow, w.unit(w.a) as fast:
            asked = await ack(slow, "subscribe", "s", topics=[plan], throttle_ms=5000)
            assert asked["ok"] is True
            assert (await ack(fast, "subscribe", "s", topics=[plan]))["ok"] is True
            for n in range(5):
                assert (await ack(op, "publish", f"p{n}", topic=plan, data=n))["ok"] is True
            assert await events_until(fast, plan, 4) == [0, 1, 2, 3, 4]
            assert (await next_json(slow, event_on(plan)))["data"] == 0


async def test_after_the_cloud_link_comes_back_a_vehicle_s_topics_go_up_once(
    make_settings: Callable[..., Settings],
) -> None:
    """The replay sends what the vehicle's units hold together, each topic once at the
    least ``throttle_ms``: not one subscribe per unit, where the last one's throttle
    would stand above for all, and after which one unit letting go would not leave the
    vehicle's other units served."""
    async with gateway(make_settings) as w:
        plan = f"user/{w.operator}/plan/{w.a}"
        vehicle = f"vehicle:{w.a}"
        async with (
            await w.operator_ws() as op,
            w.unit(w.a) as fast,
            w.unit(w.a) as slow,
            w.unit(w.b) as other,
        ):
            assert (await ack(op, "register", "r", topics=[plan]))["ok"] is True
            assert (await ack(fast, "subscribe", "s", topics=[plan]))["ok"] is True
            asked = await ack(slow, "subscribe", "s", topics=[plan], throttle_ms=1000)
            assert asked["ok"] is True
            await next_json(op, consumers(w, plan, lambda units: vehicle in units))

            await w.units.link.aclose()  # the cloud link goes down: the server forgets
            await next_json(op, consumers(w, plan, lambda units: vehicle not in units))
            # the next op that goes up opens the link again; the replay goes first
            warm = await ack(other, "subscribe", "warm", topics=[f"vehicle/{w.b}/x"])
            assert warm["ok"] is True and w.units.link.opened == 2
            await next_json(op, consumers(w, plan, lambda units: vehicle in units))
            replayed = [o for o in w.units.router.replay() if plan in o["topics"]]
            assert replayed == [{"op": "subscribe", "vehicle_id": w.a, "topics": [plan]}]

            for n in range(5):
                assert (await ack(op, "publish", f"p{n}", topic=plan, data=n))["ok"] is True
            assert await events_until(fast, plan, 4) == [0, 1, 2, 3, 4]

            assert (await ack(fast, "unsubscribe", "u", topics=[plan]))["ok"] is True
            assert (await ack(op, "publish", "after", topic=plan, data="after"))["ok"] is True
            await next_json(slow, lambda f: event_on(plan)(f) and f["data"] == "after")
            assert (await ack(slow, "unsubscribe", "u", topics=[plan]))["ok"] is True
            await next_json(op, consumers(w, plan, lambda units: vehicle not in units))


async def test_a_named_unit_connecting_again_replaces_its_stale_connection_alone(
    make_settings: Callable[..., Settings],
) -> None:
    """``?unit=<name>``: a new connection of the same vehicle and name closes the former
    one (4409) and keeps what the unit held; connections without a name, another name,
    or the same name for another vehicle are units of their own and stay."""
    async with gateway(make_settings) as w:
        plan = f"user/{w.operator}/plan/{w.a}"
        async with (
            await w.operator_ws() as op,
            w.unit(w.a, "sonar") as stale,
            w.unit(w.a) as anonymous,
        ):
            assert (await ack(stale, "subscribe", "s", topics=[plan]))["ok"] is True
            async with (
                w.unit(w.a) as another_anonymous,
                w.unit(w.a, "camera") as camera,
                w.unit(w.b, "sonar") as other_vehicle,
            ):
                assert (await ack(anonymous, "subscribe", "s", topics=[plan]))["ok"] is True
                async with w.unit(w.a, "sonar") as fresh:
                    assert await closed_with(stale) == CLOSE_REPLACED
                    assert (await ack(op, "publish", "p", topic=plan, data=1))["ok"] is True
                    for unit in (fresh, anonymous):  # the sonar's subscription kept
                        assert (await next_json(unit, event_on(plan)))["data"] == 1
                    for n, unit in enumerate((another_anonymous, camera, other_vehicle)):
                        topic = f"user/{w.operator}/goal/{w.a}"
                        assert (await ack(unit, "subscribe", f"s{n}", topics=[topic]))["ok"]
                    assert len(w.units.router.of_vehicle(w.a)) == 4


async def test_a_unit_name_must_be_an_identifier_and_its_vehicle_listed(
    make_settings: Callable[..., Settings],
) -> None:
    async with gateway(make_settings) as w:
        async with w.unit(w.a, "Sonar%20Driver") as badly_named:
            assert await closed_with(badly_named) == CLOSE_BAD_REQUEST
            assert badly_named.close_reason.startswith("unit: not a unit name (1 to 64")
        async with w.unit(w.a, "") as unnamed:  # unit= with no name was an unnamed unit
            assert await closed_with(unnamed) == CLOSE_BAD_REQUEST
            assert unnamed.close_reason.startswith("unit: not a unit name")
        async with w.unit("Bad%20Id", "sonar") as bad_vehicle:  # was "connect with ..."
            assert await closed_with(bad_vehicle) == CLOSE_BAD_REQUEST
            assert bad_vehicle.close_reason.startswith("vehicle_id: not a vehicle id (1 to 64")
        async with w.unit(f"{w.a}&vehicle_id={w.b}", "sonar") as two_vehicles:
            assert await closed_with(two_vehicles) == CLOSE_BAD_REQUEST  # was the first's
            assert "vehicle_id is given more than once" in two_vehicles.close_reason
        async with w.unit(w.a, "sonar") as ua:  # the link up: the server said whom it lists
            assert (await ack(ua, "register", "r", topics=[f"vehicle/{w.a}/x"]))["ok"] is True
            # Refused as the server refuses it: the field (topics.1), a sentence naming it.
            theirs = f"vehicle/{w.b}/x"
            refused = await ack(ua, "register", "r2", topics=[f"vehicle/{w.a}/y", theirs])
            assert refused["ok"] is False and refused["error"]["code"] == "forbidden"
            [detail] = refused["error"]["details"]
            assert detail["field"] == "topics.1" and detail["message"].startswith(f"{theirs}: ")
        async with w.unit("usv-not-ours", "sonar") as stranger:
            assert await closed_with(stranger) == CLOSE_FORBIDDEN


async def test_a_named_unit_back_while_its_former_connection_is_taken_out_is_served(
    make_settings: Callable[..., Settings],
) -> None:
    """The former connection's leaving waits for its vehicle's turn (here, another unit's
    register waiting for its routes push). The unit connecting again meanwhile used to
    have its new subscriptions dropped under it once that leaving went through."""
    async with gateway(make_settings) as w:
        plan = f"user/{w.operator}/plan/{w.a}"
        async with await w.operator_ws() as op, w.unit(w.a) as sibling:
            assert (await ack(sibling, "subscribe", "warm", topics=[f"vehicle/{w.b}/x"]))["ok"]
            told = w.units.link.on_routes
            assert told is not None
            arrived = asyncio.Event()
            loop = asyncio.get_running_loop()

            def later(push: RoutesPush) -> None:  # the register holds its turn a second
                if push.unit == f"vehicle:{w.a}":
                    arrived.set()
                loop.call_later(1.0, told, push)

            w.units.link.on_routes = later
            async with w.unit(w.a, "sonar") as sonar:
                assert (await ack(sonar, "subscribe", "s", topics=[plan]))["ok"] is True
                register = {"op": "register", "id": "r", "topics": [f"vehicle/{w.a}/new"]}
                await sibling.send(json.dumps(register))
                async with asyncio.timeout(5):
                    await arrived.wait()

            async def sonar_left() -> bool:
                return w.units.describe().startswith("1 connected")

            await eventually(sonar_left)
            async with w.unit(w.a, "sonar") as back:
                assert (await ack(back, "subscribe", "s", topics=[plan]))["ok"] is True
                w.units.link.on_routes = told
                assert (await ack(op, "publish", "p", topic=plan, data=1))["ok"] is True
                assert (await next_json(back, event_on(plan)))["data"] == 1


async def test_a_unit_that_subscribes_after_another_of_its_vehicle_gets_the_topic_s_state(
    make_settings: Callable[..., Settings],
) -> None:
    """The server answers a new subscriber with a topic's latest message (its state, with
    ``snapshot: true``); the first unit of a vehicle got it from above, but a second one,
    answered by the gateway (the vehicle holds the topic above already), got nothing
    until the next publish. A sibling's publish kept below (nobody above asked for it) is
    the topic's state for a unit that subscribes later too; a topic the server writes
    has none."""
    async with gateway(make_settings) as w:
        plan = f"user/{w.operator}/plan/{w.a}"
        sonar = f"vehicle/{w.a}/sonar_meta"
        commands = f"vehicle/{w.a}/commands"
        async with await w.operator_ws() as op, w.unit(w.a) as first, w.unit(w.a) as driver:
            assert (await ack(op, "publish", "p1", topic=plan, data={"leg": 1}))["ok"] is True
            assert (await ack(first, "subscribe", "s", topics=[plan, commands]))["ok"] is True
            state = await next_json(first, event_on(plan))
            assert (state["data"], state["snapshot"]) == ({"leg": 1}, True)
            assert (await ack(first, "subscribe", "s2", topics=[sonar]))["ok"] is True
            assert (await ack(driver, "publish", "p2", topic=sonar, data=7))["ok"] is True
            assert (await next_json(first, event_on(sonar)))["data"] == 7

            async with w.unit(w.a) as second:
                topics = [plan, sonar, commands]
                assert (await ack(second, "subscribe", "s", topics=topics))["ok"] is True
                got = [await next_json(second, lambda f: f["op"] == "event") for _ in range(2)]
                assert {f["topic"]: (f["data"], f["snapshot"]) for f in got} == {
                    plan: ({"leg": 1}, True),
                    sonar: (7, True),
                }
                assert (await ack(op, "publish", "p3", topic=plan, data={"leg": 2}))["ok"] is True
                after = await next_json(second, lambda f: f["op"] == "event")
                assert (after["topic"], after["data"]) == (plan, {"leg": 2})
                assert not after.get("snapshot")  # nothing more was said of the others


async def test_the_first_unit_of_a_vehicle_to_subscribe_gets_a_sibling_s_message_as_state(
    make_settings: Callable[..., Settings],
) -> None:
    """Its subscribe goes up, and the server has no state to send for a message of this
    gateway's own units: it never had it (nobody above asked), or had it from this very
    socket and keeps it back (no echo). The gateway's latest is the state, as for a unit
    it answers itself: a unit of the same vehicle, or of its neighbour, got nothing."""
    async with gateway(make_settings) as w:
        status = f"vehicle/{w.a}/status"
        async with await w.operator_ws() as op, w.unit(w.a) as driver:
            warm = f"vehicle/{w.b}/other"  # the link up (its agents' job)
            assert (await ack(driver, "subscribe", "warm", topics=[warm]))["ok"] is True
            assert (await ack(driver, "publish", "p1", topic=status, data=1))["ok"] is True
            async with w.unit(w.a) as mission:  # kept below: nobody above asked
                assert (await ack(mission, "subscribe", "s", topics=[status]))["ok"] is True
                state = await next_json(mission, event_on(status), within_s=2)
                assert (state["data"], state["snapshot"]) == (1, True)
            await units_of(w, w.a, 1)
            assert (await ack(op, "subscribe", "s", topics=[status]))["ok"] is True

            async def asked_above() -> bool:
                return status in w.units.router.forward_up

            await eventually(asked_above)
            assert (await ack(driver, "publish", "p2", topic=status, data=2))["ok"] is True
            assert (await next_json(op, event_on(status)))["data"] == 2  # kept above too
            async with w.unit(w.b) as neighbour:
                assert (await ack(neighbour, "subscribe", "s", topics=[status]))["ok"] is True
                state = await next_json(neighbour, event_on(status), within_s=2)
                assert (state["data"], state["snapshot"]) == (2, True)
