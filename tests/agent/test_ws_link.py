"""The WebSocket transport: its pure parts, then the link against a tiny scripted socket."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import asynccontextmanager
from typing import Any

import pytest
from websockets.asyncio.server import ServerConnection, serve

from fleet_protocol import ErrorBody, StartInstance
from fleet_protocol.ws import AckPush, CommandPush, RoutesPush
from vehicle_client.errors import FatalError, RetryableError, SessionLost, TokenRefused
from vehicle_client.gateway.forwarding import LocalUnit, TopicRouter, write_refusal
from vehicle_client.transport.auto import LinkChoice
from vehicle_client.transport.wire import (
    IdSource,
    PushError,
    ack_error,
    batches,
    close_error,
    parse_push,
    ws_url,
)
from vehicle_client.transport.ws import WsLink, WsUnavailable

# -- pure -------------------------------------------------------------------------


def test_ws_url_follows_the_server_url() -> None:
    assert ws_url("http://h:8000") == "ws://h:8000/ws/vehicle"
    assert ws_url("https://h/fleet/") == "wss://h/fleet/ws/vehicle"
    with pytest.raises(FatalError):
        ws_url("h:8000")


def test_op_ids_are_unique_per_link() -> None:
    ids = IdSource("x-")
    assert [ids.next() for _ in range(3)] == ["x-1", "x-2", "x-3"]


def test_one_op_goes_alone_more_go_as_batches_within_the_limit() -> None:
    ops = [{"op": "heartbeat", "id": str(i), "instance_id": "i"} for i in range(5)]
    assert [json.loads(f) for f in batches(ops[:1])] == [ops[0]]
    frames = [json.loads(f) for f in batches(ops, limit=2)]
    assert [f["op"] for f in frames] == ["batch", "batch", "heartbeat"]
    assert [op["id"] for f in frames[:2] for op in f["ops"]] == ["0", "1", "2", "3"]
    assert all("id" not in f for f in frames[:2])  # inner ops are acked, not the batch


@pytest.mark.parametrize(
    ("code", "kind", "says"),
    [
        (4401, TokenRefused, "token"),  # a FatalError a gateway tells its units of
        (4403, FatalError, "may not act"),
        (4409, FatalError, "another agent"),
        (1001, RetryableError, "1001"),
        (None, RetryableError, "None"),
    ],
)
def test_close_codes(code: int | None, kind: type[Exception], says: str) -> None:
    error = close_error(code, "why")
    assert type(error) is kind and says in str(error)


def test_refused_ops_are_sorted_like_http_statuses() -> None:
    def refused(code: str) -> AckPush:
        return AckPush.failure("1", ErrorBody(code=code, message="m"))

    assert isinstance(ack_error(refused("forbidden"), "op"), FatalError)
    assert isinstance(ack_error(refused("unauthorized"), "op"), TokenRefused)
    assert isinstance(ack_error(refused("not_found"), "op"), SessionLost)
    assert type(ack_error(refused("rate_limited"), "op")) is RetryableError


def test_pushes_parse_by_op_and_bad_ones_are_named() -> None:
    ack = parse_push('{"op":"ack","id":"7","ok":true,"accepted":3}')
    assert isinstance(ack, AckPush) and ack.accepted == 3  # type: ignore[attr-defined]
    routes = parse_push('{"op":"routes","unit":"gateway:g","forward_up":["vehicle/a/x"]}')
    assert isinstance(routes, RoutesPush) and routes.forward_up == ["vehicle/a/x"]
    with pytest.raises(PushError, match="op"):
        parse_push('{"op":"launch"}')


def test_link_choice_falls_back_then_retries_the_websocket_sooner_first() -> None:
    """5 s after a first refusal (a server restarting behind a proxy is back soon), the
    wait doubling with each refusal in a row up to retry_ws_s (a proxy that never
    upgrades), and 5 s again once the WebSocket was open."""
    now = [100.0]
    choice = LinkChoice(retry_ws_s=60, clock=lambda: now[0])
    assert choice.use_ws() and choice.mode == "ws"
    for wait in (5, 10, 20, 40, 60, 60):
        choice.refused("403")
        assert choice.mode == "http" and not choice.use_ws()
        now[0] += wait - 0.1
        assert not choice.use_ws(), wait
        now[0] += 0.2
        assert choice.use_ws(), wait
    choice.opened()
    assert choice.mode == "ws" and choice.fallbacks == 1
    choice.refused("502")
    now[0] += 5.1
    assert choice.use_ws() and choice.fallbacks == 2


def test_router_keeps_local_what_local_units_consume() -> None:
    router = TopicRouter()
    a, b = LocalUnit("a", "#1"), LocalUnit("b", "#2")
    for unit in (a, b):
        router.add(unit)
    router.register(a, ["vehicle/a/sonar"])
    router.subscribe(b, ["vehicle/a/sonar"])
    first = router.publish(a, "vehicle/a/sonar")
    assert first.local == [b] and first.up is False
    # Someone above asks (a table that has not yet heard of b's subscription): a unit
    # below consumes it, so it stays below all the same.
    assert router.routes("gateway:g", ["vehicle/a/sonar"], []) is None
    second = router.publish(a, "vehicle/a/sonar")
    assert second.local == [b] and second.up is False
    router.unsubscribe(b, ["vehicle/a/sonar"])
    third = router.publish(a, "vehicle/a/sonar")
    assert third.local == [] and third.up is True
    assert (router.sent_up, router.kept_local) == (1, 2)
    # Not registered (the table above cannot say who wants it): up, unless consumed here.
    assert router.publish(a, "vehicle/a/other").up is True
    router.subscribe(b, ["vehicle/a/other"])
    assert router.publish(a, "vehicle/a/other").up is False


def test_router_drops_its_own_media_frame_coming_back_from_above() -> None:
    """The server filters a JSON event by the socket it came from, not a media frame: one
    on a topic of a vehicle with a unit here is the gateway's own, which its units had."""
    router = TopicRouter()
    a, b = LocalUnit("a", "#1"), LocalUnit("b", "#2")
    for unit in (a, b):
        router.add(unit)
    router.subscribe(b, ["vehicle/a/cam", "vehicle/c/cam"])
    assert router.from_above("vehicle/a/cam", media=True) == []
    assert router.from_above("vehicle/c/cam", media=True) == [b]  # no unit of c here
    assert router.from_above("vehicle/a/cam") == [b]  # JSON: filtered by the server
    router.drop(a)
    assert router.from_above("vehicle/a/cam", media=True) == [b]


def test_router_delivers_from_above_and_replays_after_a_reconnection() -> None:
    router = TopicRouter()
    a = LocalUnit("a", "#1")
    router.add(a)
    router.subscribe(a, ["user/op/plan"])
    router.register(a, ["vehicle/a/x"])
    assert router.from_above("user/op/plan") == [a] and router.from_above("user/op/q") == []
    assert router.routes("vehicle:a", [], []) == "a"
    assert router.routes("vehicle:zz", [], []) is None
    router.subscribe(a, ["user/op/slow"], throttle_ms=500)
    assert router.replay() == [
        {"op": "register", "vehicle_id": "a", "topics": ["vehicle/a/x"]},
        {"op": "subscribe", "vehicle_id": "a", "topics": ["user/op/plan"]},
        {"op": "subscribe", "vehicle_id": "a", "topics": ["user/op/slow"], "throttle_ms": 500},
    ]
    router.drop(a)
    assert router.replay() == []


def test_router_tells_the_server_what_a_vehicle_s_units_hold_together() -> None:
    """Several units of one vehicle: a topic goes up with the first, is taken back with
    the last, at the least throttle_ms any of them asked; the replay sends the union."""
    router = TopicRouter()
    sonar, script, other = LocalUnit("a", "sonar"), LocalUnit("a", "#1"), LocalUnit("b", "#2")
    for unit in (sonar, script, other):
        router.add(unit)
    plan, x = "user/op/plan/a", "vehicle/a/x"
    up = {"op": "subscribe", "vehicle_id": "a", "topics": [plan]}
    assert router.ops_for(sonar, consumes={plan: 500}) == [{**up, "throttle_ms": 500}]
    router.subscribe(sonar, [plan], 500)
    assert router.ops_for(script, consumes={plan: 800}) == []  # held, at 500 still
    assert router.ops_for(other, consumes={plan: 800}) == [
        {**up, "vehicle_id": "b", "throttle_ms": 800}
    ]
    assert router.ops_for(script, consumes={plan: 0}) == [up]  # more often: asked again
    router.subscribe(script, [plan], 0)
    assert router.replay() == [up]
    assert router.ops_for(script, consumes={}) == [{**up, "throttle_ms": 500}]  # back to 500
    assert router.ops_for(sonar, produces=set(), consumes={}) == []  # script still holds
    router.unsubscribe(sonar, [plan])
    assert router.ops_for(script, consumes={}) == [{**up, "op": "unsubscribe"}]
    register = {"op": "register", "vehicle_id": "a", "topics": [x]}
    assert router.ops_for(sonar, produces={x}) == [register]
    router.register(sonar, [x])
    assert router.ops_for(script, produces={x}) == []
    router.register(script, [x])
    assert router.ops_for(sonar, produces=set()) == []
    router.drop(sonar)
    assert router.ops_for(script, produces=set(), consumes={}) == [
        {**up, "op": "unsubscribe"},
        {**register, "op": "unregister"},
    ]


def test_units_write_only_their_own_vehicle_topics() -> None:
    assert write_refusal("a", "vehicle/a/sonar") is None
    assert "vehicle/a/" in (write_refusal("a", "vehicle/b/sonar") or "")
    assert "server alone" in (write_refusal("a", "vehicle/a/telemetry") or "")
    assert write_refusal("a", "user/a/x") is not None


# -- the link against a scripted socket ----------------------------------------------

Script = Callable[[ServerConnection, dict[str, Any]], Awaitable[None]]


@asynccontextmanager
async def scripted(answer: Script) -> AsyncIterator[tuple[str, list[dict[str, Any]]]]:
    """A socket that records every frame and runs ``answer`` on each op in it."""
    frames: list[dict[str, Any]] = []

    async def handler(conn: ServerConnection) -> None:
        async for raw in conn:
            frame = json.loads(raw)
            frames.append(frame)
            for op in frame["ops"] if frame["op"] == "batch" else [frame]:
                await answer(conn, op)

    async with serve(handler, "127.0.0.1", 0, compression=None) as server:
        port = server.sockets[0].getsockname()[1]
        yield f"http://127.0.0.1:{port}", frames


def started(op: dict[str, Any]) -> str:
    return AckPush.success(
        op["id"],
        {
            "instance_id": f"i-{op['vehicle_id']}",
            "resumed": False,
            "last_seq": 0,
            "heartbeat_interval_s": 1,
            "stale_after_s": 3,
            "offline_after_s": 10,
            "ack_timeout_s": 10,
            "server_time": "2026-11-22T10:00:00.000Z",
            "failsafe": {"after_s": 30, "action": "keep_station"},
        },
    ).frame()


def command(instance_id: str) -> str:
    return CommandPush.model_validate(
        {
            "command_id": "c1",
            "instance_id": instance_id,
            "type": "stop",
            "args": {},
            "status": "delivered",
            "issued_by": "op",
            "issued_at": "2026-11-22T10:00:00.000Z",
            "expires_at": "2026-11-22T10:10:00.000Z",
        }
    ).frame()


async def test_a_gateway_tick_sends_its_vehicles_ops_as_one_batch_and_routes_pushes() -> None:
    async def answer(conn: ServerConnection, op: dict[str, Any]) -> None:
        await conn.send(started(op))
        await conn.send(command(f"i-{op['vehicle_id']}"))  # after the ack, like the server

    async with scripted(answer) as (url, frames):
        link = WsLink(url, "t", batch_tick_s=0.05)
        a, b, c = link.vehicle("a"), link.vehicle("b"), link.vehicle("c")
        try:
            ra, rb, rc = await asyncio.gather(
                *(v.start_instance(StartInstance(vehicle_id=v.vehicle_id)) for v in (a, b, c))
            )
            assert (ra.instance_id, rb.instance_id, rc.instance_id) == ("i-a", "i-b", "i-c")
            # the first finds nothing in flight and goes at once; the others, sent while it
            # awaits its ack, wait for the tick and leave together
            assert [f["op"] for f in frames] == ["start_instance", "batch"]
            assert len(frames[1]["ops"]) == 2
            got = await asyncio.wait_for(b.get_control("i-b", 0), 5)
            assert [c.instance_id for c in got.commands] == ["i-b"]
        finally:
            await link.aclose()


async def test_an_op_on_an_idle_gateway_link_is_not_held_for_the_tick() -> None:
    async def answer(conn: ServerConnection, op: dict[str, Any]) -> None:
        await conn.send(started(op))

    async with scripted(answer) as (url, frames):
        link = WsLink(url, "t", batch_tick_s=30.0)  # a tick far longer than the wait below
        try:
            started_a = link.vehicle("a").start_instance(StartInstance(vehicle_id="a"))
            assert (await asyncio.wait_for(started_a, 5)).instance_id == "i-a"
            assert [f["op"] for f in frames] == ["start_instance"]
        finally:
            await link.aclose()


async def test_replaced_close_is_fatal_with_a_clear_message_and_stays_fatal() -> None:
    async def answer(conn: ServerConnection, op: dict[str, Any]) -> None:
        await conn.send(started(op))
        await conn.close(4409, "another connection took this vehicle")

    async with scripted(answer) as (url, _):
        link = WsLink(url, "t")
        vehicle = link.vehicle("a")
        try:
            await vehicle.start_instance(StartInstance(vehicle_id="a"))
            with pytest.raises(FatalError, match="another agent"):
                await asyncio.wait_for(vehicle.get_control("i-a", 0), 5)
            with pytest.raises(FatalError):
                await vehicle.heartbeat("i-a")
        finally:
            await link.aclose()


async def test_an_op_without_an_ack_in_time_breaks_the_link_for_a_retry() -> None:
    async def silent(conn: ServerConnection, op: dict[str, Any]) -> None:
        return None

    async with scripted(silent) as (url, _):
        link = WsLink(url, "t", ack_timeout_s=0.2)
        try:
            with pytest.raises(RetryableError, match="no ack"):
                await link.vehicle("a").heartbeat("i-a")
            assert not link.connected
        finally:
            await link.aclose()


async def test_a_refused_upgrade_is_websocket_unavailable() -> None:
    async def http_only(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        await reader.readuntil(b"\r\n\r\n")
        writer.write(b"HTTP/1.1 404 Not Found\r\nContent-Length: 0\r\n\r\n")
        await writer.drain()
        writer.close()

    server = await asyncio.start_server(http_only, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    link = WsLink(f"http://127.0.0.1:{port}", "t")
    try:
        with pytest.raises(WsUnavailable):
            await link.vehicle("a").heartbeat("i-a")
    finally:
        await link.aclose()
        server.close()


def test_a_refusal_followed_by_http_failing_too_is_taken_back() -> None:
    """The server away (both ways fail) says nothing of its WebSocket: the next session
    tries it first, not after a wait doubled through the outage."""
    now = [100.0]
    choice = LinkChoice(retry_ws_s=60, clock=lambda: now[0])
    choice.refused("403")  # a real refusal: HTTP worked after it
    for _ in range(4):  # then an outage: the WebSocket refused, HTTP failing as well
        now[0] += choice.wait_s
        assert choice.use_ws()
        choice.refused("502")
        choice.unheard()
    assert choice.refusals == 1 and choice.wait_s == 5
    choice.unheard()
    assert choice.mode == "ws" and choice.use_ws()
