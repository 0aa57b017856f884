"""A gateway's local units and the table above: what a unit leaves behind, whom the
gateway takes, what goes up (a real server in this process, as in test_gateway_media)."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Callable
from typing import Any

import pytest
import websockets

from fleet_protocol.links import CLOSE_FORBIDDEN, MAX_TEXT_FRAME_BYTES
from fleet_protocol.ws import RoutesPush
from server.settings import Settings
from tests.agent.test_gateway_media import ack, event_on, gateway, next_json
from tests.server.commanding import eventually


async def test_a_unit_that_leaves_takes_its_registrations_back_upstream(
    make_settings: Callable[..., Settings],
) -> None:
    """Its topics no longer count against its bound above (256 topics a unit): a unit
    that comes back three times with 200 new topics each is not refused."""
    async with gateway(make_settings) as w:
        for round_ in range(3):
            async with w.unit(w.b) as ub:
                for part in range(4):  # 64 topics an op at most
                    topics = [f"vehicle/{w.b}/sensor/r{round_}-{part}-{k}" for k in range(50)]
                    answer = await ack(ub, "register", f"r{round_}{part}", topics=topics)
                    assert answer["ok"] is True, answer
            deadline = asyncio.get_running_loop().time() + 10
            while w.units.router.of_vehicle(w.b):  # until the gateway saw it leave
                assert asyncio.get_running_loop().time() < deadline, "the unit never left"
                await asyncio.sleep(0.02)


async def test_a_topic_the_unit_did_not_register_still_reaches_a_subscriber_above(
    make_settings: Callable[..., Settings],
) -> None:
    """As a publish straight to the server does; it was acked and dropped."""
    async with gateway(make_settings) as w:
        depth = f"vehicle/{w.a}/sensor/depth"
        async with await w.operator_ws() as op, w.unit(w.a) as ua:
            assert (await ack(op, "subscribe", "s", topics=[depth]))["ok"] is True
            other = f"vehicle/{w.a}/sensor/other"  # the gateway's link up (its agents' job)
            assert (await ack(ua, "register", "r", topics=[other]))["ok"] is True
            assert (await ack(ua, "publish", "p", topic=depth, data={"m": 4.2}))["ok"] is True
            got = await next_json(op, event_on(depth))
            assert got["data"] == {"m": 4.2}


async def test_json_on_a_media_topic_and_a_refused_subscribe_leave_nothing_behind(
    make_settings: Callable[..., Settings],
) -> None:
    async with gateway(make_settings) as w:
        cam = f"vehicle/{w.a}/camera/front"
        async with w.unit(w.a) as ua:
            refused = await ack(ua, "publish", "p", topic=cam, data={"x": 1})
            assert refused["ok"] is False and "binary frames" in refused["error"]["message"]
            # b's topics are not a's to read... but a unit reads its neighbour's vehicle
            # only with read access: refused above, so not kept here to replay later
            secret = "user/someone-else/notes"
            answer = await ack(ua, "subscribe", "s", topics=[secret])
            assert answer["ok"] is False
            assert secret not in w.units.router.held(w.a).consumes


async def test_a_unit_in_a_publish_loop_is_told_when_over_its_share_of_the_uplink(
    make_settings: Callable[..., Settings],
) -> None:
    """Over the units' publishes a second, a publish is refused to its unit (rate_limited),
    not acked ok and then refused above, and the vehicles' ops keep the socket."""
    async with gateway(make_settings, publish_up_per_s=20) as w:
        depth = f"vehicle/{w.a}/sensor/depth"
        async with await w.operator_ws() as op, w.unit(w.a) as ua:
            assert (await ack(op, "subscribe", "s", topics=[depth]))["ok"] is True
            assert (await ack(ua, "register", "r", topics=[depth]))["ok"] is True
            # (the routes that send it up came before that ack)
            answers = [await ack(ua, "publish", f"p{n}", topic=depth, data=n) for n in range(60)]
            refused = [a for a in answers if not a["ok"]]
            assert refused and all(a["error"]["code"] == "rate_limited" for a in refused)
            assert len(refused) < 60 - 15  # about a second's worth went first
            assert w.units.publish_budget.refused == len(refused)
            # what was acked ok reaches the subscriber above: nothing said ok was dropped
            sent = [n for n, a in enumerate(answers) if a["ok"]]
            got = []
            while len(got) < len(sent):
                got.append((await next_json(op, event_on(depth)))["data"])
            assert got == sent


async def test_a_unit_of_a_vehicle_the_token_does_not_list_is_closed(
    make_settings: Callable[..., Settings],
) -> None:
    """Once the server said whom the gateway acts for: a unit connected before that is
    closed when the link opens, one connecting after is closed at once (4403, why)."""
    async with gateway(make_settings) as w:
        async with w.unit("usv-not-ours") as stranger, w.unit(w.a) as ua:
            # the unit's op opens the link; whoami comes first
            assert (await ack(ua, "register", "r", topics=[f"vehicle/{w.a}/x"]))["ok"] is True
            with pytest.raises(websockets.ConnectionClosed):
                await next_json(stranger, lambda f: False)
            assert stranger.close_code == CLOSE_FORBIDDEN
            assert "does not act for usv-not-ours" in (stranger.close_reason or "")
        assert w.units.acts_for == {w.a, w.b}
        async with w.unit("usv-not-ours") as late:
            with pytest.raises(websockets.ConnectionClosed):
                await next_json(late, lambda f: False)
            assert late.close_code == CLOSE_FORBIDDEN
        async with w.unit(w.b) as ub:  # the listed ones are still taken
            assert (await ack(ub, "register", "r", topics=[f"vehicle/{w.b}/x"]))["ok"] is True


async def test_a_topic_goes_up_only_when_someone_above_asks_and_no_unit_below_consumes_it(
    make_settings: Callable[..., Settings],
) -> None:
    """API.md: a gateway forwards up what its own units do not consume and someone above
    subscribed to. A unit's first publish on a topic registers it above for the unit."""
    async with gateway(make_settings) as w:
        depth = f"vehicle/{w.a}/sensor/depth"
        router = w.units.router
        async with await w.operator_ws() as op, w.unit(w.a) as ua, w.unit(w.b) as ub:
            assert (await ack(ub, "subscribe", "s", topics=[depth]))["ok"] is True  # a sibling
            up_before = router.sent_up
            assert (await ack(ua, "publish", "p1", topic=depth, data=1))["ok"] is True
            assert (await next_json(ub, event_on(depth)))["data"] == 1
            assert router.sent_up == up_before  # only a sibling wants it: kept below
            assert depth in router.held(w.a).produces  # registered above for the unit

            # Asked above too: a unit below consumes it, so it still stays below.
            assert (await ack(op, "subscribe", "s", topics=[depth]))["ok"] is True
            assert (await ack(ua, "publish", "p2", topic=depth, data=2))["ok"] is True
            assert (await next_json(ub, event_on(depth)))["data"] == 2
            assert router.sent_up == up_before and depth not in router.forward_up

            # No unit below consumes it any more: up, on the table's word.
            assert (await ack(ub, "unsubscribe", "u", topics=[depth]))["ok"] is True

            async def asked_above() -> bool:  # the routes push, on the gateway's own socket
                return depth in router.forward_up

            await eventually(asked_above)
            assert (await ack(ua, "publish", "p3", topic=depth, data=3))["ok"] is True
            # The operator's first event on it is p3's: p2 never went up.
            assert (await next_json(op, event_on(depth)))["data"] == 3
            assert router.sent_up == up_before + 1


async def _routes_late(w: Any, unit: Any) -> None:
    """The link up (it opens with the first op sent through it: the failure to see is
    one of order, not of a link down), then each routes push handed to the gateway a
    moment behind the ack before it, as through a relay or a slow network that hands
    each frame over apart."""
    other = f"vehicle/{w.b}/status"
    assert (await ack(unit, "subscribe", "warm", topics=[other]))["ok"] is True
    told = w.units.link.on_routes
    assert told is not None
    loop = asyncio.get_running_loop()

    def later(push: RoutesPush) -> None:
        loop.call_later(0.3, told, push)

    w.units.link.on_routes = later


async def test_a_unit_s_first_publish_reaches_who_already_asked_above(
    make_settings: Callable[..., Settings],
) -> None:
    """Someone above subscribed before the unit ever spoke: its first publish on the topic
    (registered above on the way) goes up at once, not only the ones after it. The
    register's ack came before the routes push that says someone above wants it."""
    async with gateway(make_settings) as w:
        async with await w.operator_ws() as op, w.unit(w.a) as ua:
            await _routes_late(w, ua)
            for n in range(5):  # a new topic each time: each its own first publish
                topic = f"vehicle/{w.a}/survey/{n}"
                assert (await ack(op, "subscribe", f"s{n}", topics=[topic]))["ok"] is True
                said = await ack(ua, "publish", f"p{n}", topic=topic, data=n)
                assert said["ok"] is True, said
                assert (await next_json(op, event_on(topic)))["data"] == n


async def test_a_unit_that_publishes_the_moment_its_register_is_acked_reaches_above(
    make_settings: Callable[..., Settings],
) -> None:
    """The register's ack is passed down once the routes push that follows it came: a
    unit publishing at once used to be kept local (the gateway did not know yet that
    someone above wants the topic), acknowledged ok and lost above."""
    async with gateway(make_settings) as w:
        async with await w.operator_ws() as op, w.unit(w.a) as ua:
            await _routes_late(w, ua)
            for n in range(3):
                topics = [f"vehicle/{w.a}/meta/{n}", f"vehicle/{w.a}/meta/{n}/more"]
                assert (await ack(op, "subscribe", f"s{n}", topics=topics[:1]))["ok"] is True
                assert (await ack(ua, "register", f"r{n}", topics=topics))["ok"] is True
                said = await ack(ua, "publish", f"p{n}", topic=topics[0], data=n)
                assert said["ok"] is True, said
                assert (await next_json(op, event_on(topics[0])))["data"] == n


async def test_a_local_unit_gets_its_topic_at_the_throttle_it_asked(
    make_settings: Callable[..., Settings],
) -> None:
    """``throttle_ms`` holds for a unit behind the gateway as on the server's sockets: at
    most one event a period, the latest held back going when it is over. The gateway
    used to hand every event to its units whatever they asked."""
    async with gateway(make_settings) as w:
        async with w.unit(w.a) as ua, w.unit(w.b) as ub:
            topic = f"vehicle/{w.a}/status"
            asked = await ack(ub, "subscribe", "s", topics=[topic], throttle_ms=2000)
            assert asked["ok"] is True
            for n in range(10):
                assert (await ack(ua, "publish", f"p{n}", topic=topic, data=n))["ok"] is True
            first = await next_json(ub, event_on(topic))
            then = await next_json(ub, event_on(topic))
            assert (first["data"], then["data"]) == (0, 9)


async def test_units_subscribe_and_register_among_themselves_while_the_cloud_link_is_down(
    make_settings: Callable[..., Settings],
) -> None:
    """A unit restarted at sea, the cloud out of reach: it still gets the data of the unit
    beside it (it used to be refused, unavailable); the ops go up with the replay."""
    async with gateway(make_settings) as w:
        async with w.unit(w.a) as ua, w.unit(w.b) as ub:
            assert (await ack(ub, "subscribe", "warm", topics=[f"vehicle/{w.b}/x"]))["ok"]
            w.units.link.url = "ws://127.0.0.1:1/ws/vehicle"  # the cloud out of reach
            await w.units.link.aclose()  # and the link goes down
            depth = f"vehicle/{w.a}/sensor/depth"
            taken = await ack(ub, "subscribe", "s", topics=[depth])
            assert (taken["ok"], taken["local_only"]) == (True, True)
            registered = await ack(ua, "register", "r", topics=[depth])
            assert (registered["ok"], registered["local_only"]) == (True, True)
            assert (await ack(ua, "publish", "p", topic=depth, data=7))["ok"] is True
            assert (await next_json(ub, event_on(depth)))["data"] == 7
            replay = w.units.router.replay()
            replayed = {(op["op"], op["vehicle_id"], t) for op in replay for t in op["topics"]}
            assert {("subscribe", w.b, depth), ("register", w.a, depth)} <= replayed


async def test_a_publish_that_cannot_go_up_is_not_acked_ok(
    make_settings: Callable[..., Settings],
) -> None:
    """The link down, or a frame too large once it names its vehicle: the unit is told
    (the local units have it all the same), never acked ok for what was dropped."""
    async with gateway(make_settings) as w:
        depth = f"vehicle/{w.a}/sensor/depth"
        async with await w.operator_ws() as op, w.unit(w.a) as ua:
            assert (await ack(op, "subscribe", "s", topics=[depth]))["ok"] is True
            assert (await ack(ua, "register", "r", topics=[depth]))["ok"] is True
            # Under a JSON frame's bound as the unit sends it; over it sent up.
            up = {"op": "publish", "vehicle_id": w.a, "topic": depth, "data": ""}
            data = "x" * (MAX_TEXT_FRAME_BYTES + 1 - len(json.dumps(up, separators=(",", ":"))))
            sent = {"op": "publish", "id": "big", "topic": depth, "data": data}
            assert len(json.dumps(sent, separators=(",", ":"))) <= MAX_TEXT_FRAME_BYTES
            await ua.send(json.dumps(sent, separators=(",", ":")))
            big = await next_json(ua, lambda f: f["op"] == "ack" and f["id"] == "big")
            assert big["ok"] is False and big["error"]["code"] == "too_large", big
            assert w.units.link.connected  # the uplink kept (the server would close it: 1009)
            await w.units.link.aclose()  # the cloud link goes down
            down = await ack(ua, "publish", "p", topic=depth, data=3)
            assert down["ok"] is False and down["error"]["code"] == "unavailable", down


async def test_events_from_above_reach_a_unit_as_they_came_source_and_ts_included(
    make_settings: Callable[..., Settings],
) -> None:
    """docs/live.md: events from above come down as they came; the contract's ``event``
    names its ``source`` and ``ts``. The gateway rebuilt each one from a model without
    ``source``: its units got an operator's message (a live one, the state relayed after
    a subscribe, the state it answers a later unit with) not knowing who sent it, where
    a socket on the server gets it. Events between its own units carry neither."""
    async with gateway(make_settings) as w:
        note, status = f"user/{w.operator}/src/{w.a}", f"vehicle/{w.a}/status"
        async with (
            await w.operator_ws() as op,
            await w.operator_ws() as direct,  # the same event, straight from the server
            w.unit(w.a) as first,
            w.unit(w.a) as driver,
        ):
            assert (await ack(op, "publish", "p1", topic=note, data={"x": 1}))["ok"] is True
            assert (await ack(direct, "subscribe", "s", topics=[note]))["ok"] is True
            state = await next_json(direct, event_on(note))
            assert (state["source"], state["snapshot"]) == (f"user:{w.operator}", True)
            assert (await ack(first, "subscribe", "s", topics=[note, status]))["ok"] is True
            assert await next_json(first, event_on(note)) == state  # relayed from above

            assert (await ack(op, "publish", "p2", topic=note, data={"x": 2}))["ok"] is True
            live = await next_json(direct, event_on(note))
            assert {"source", "ts"} <= live.keys() and "snapshot" not in live, live
            assert await next_json(first, event_on(note)) == live
            async with w.unit(w.a) as second:  # answered by the gateway, from what it kept
                assert (await ack(second, "subscribe", "s", topics=[note]))["ok"] is True
                assert await next_json(second, event_on(note)) == {**live, "snapshot": True}

            assert (await ack(driver, "publish", "p3", topic=status, data=3))["ok"] is True
            beside = await next_json(first, event_on(status))
            assert beside == {"op": "event", "topic": status, "data": 3}  # a unit's, within
