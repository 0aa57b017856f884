"""The live sockets' direct path (``server.api.ws_direct``): real uvicorn with the fleet's
protocol, where a message that needs no waiting is handled as it is read and one that
waits is finished by a task. What must hold: each socket's ops run and are answered in
the order sent, whichever path each takes; messages sent before the socket is ready are
not lost; a fault closes that socket alone (1011)."""

from __future__ import annotations

import asyncio
import json
from typing import Any

import httpx
import pytest
import websockets

from server.api.ws_ops import OpRunner
from server.services.auth import AuthService
from tests.factories import ADMIN, make_user, make_vehicle, sample
from tests.live import call, connect, recv_json, recv_until

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")

CAPS = ["stop", "go_to", "keep_station", "follow_path"]


def tok(headers: dict[str, str]) -> str:
    return headers["Authorization"].removeprefix("Bearer ")


async def acks(ws: Any, count: int) -> list[tuple[str, bool]]:
    """The next ``count`` acks, as (id, ok), in the order they came."""
    got: list[tuple[str, bool]] = []
    while len(got) < count:
        frame = await recv_until(ws, lambda f: f["op"] == "ack")
        got.append((frame["id"], frame["ok"]))
    return got


async def test_ops_sent_back_to_back_are_answered_in_the_order_sent(
    base: str, api: httpx.AsyncClient
) -> None:
    name, user = await make_user(api, "viewer", [])
    topic = f"user/{name}/track"
    async with (
        await connect(base, "/ws/client", tok(user)) as ws,
        await connect(base, "/ws/client", tok(user)) as listener,  # its own topic: the user
    ):
        assert (await call(listener, "subscribe", "l", topics=[topic]))["ok"]
        # subscribe and unsubscribe wait (a task finishes them); publish does not: sent
        # without waiting for any answer, the publishes must still come after them.
        ops: list[dict[str, Any]] = [
            {"op": "subscribe", "id": "1", "topics": [f"user/{name}/other"]},
            {"op": "publish", "id": "2", "topic": topic, "data": {"n": 2}},
            {"op": "unsubscribe", "id": "3", "topics": [f"user/{name}/other"]},
            {"op": "publish", "id": "4", "topic": topic, "data": {"n": 4}},
            {"op": "publish", "id": "5", "topic": "fleet", "data": {}},  # refused
            {"op": "publish", "id": "6", "topic": topic, "data": {"n": 6}},
        ]
        for op in ops:
            await ws.send(json.dumps(op))
        assert await acks(ws, 6) == [
            ("1", True), ("2", True), ("3", True), ("4", True), ("5", False), ("6", True)
        ]  # fmt: skip
        seen = [(await recv_until(listener, lambda f: f["op"] == "event"))["data"]["n"]]
        seen.append((await recv_until(listener, lambda f: f["op"] == "event"))["data"]["n"])
        seen.append((await recv_until(listener, lambda f: f["op"] == "event"))["data"]["n"])
        assert seen == [2, 4, 6]
        # A burst larger than the server handles for one socket in one loop turn.
        burst = [
            json.dumps({"op": "publish", "id": f"b{n}", "topic": topic, "data": {"n": n}})
            for n in range(300)
        ]
        for frame in burst:
            await ws.send(frame)
        assert [i for i, _ in await acks(ws, 300)] == [f"b{n}" for n in range(300)]
        for n in range(300):
            assert (await recv_until(listener, lambda f: f["op"] == "event"))["data"]["n"] == n


async def test_a_vehicles_samples_and_publishes_keep_their_order(
    base: str, api: httpx.AsyncClient
) -> None:
    vid, vh = await make_vehicle(api)
    async with await connect(base, "/ws/vehicle", tok(vh)) as ws:
        ack = await call(ws, "start_instance", "s", vehicle_id=vid, capabilities=CAPS)
        iid = ack["instance_id"]
        # update_param waits on the store, publish does not; 40 messages sent at once
        # are more than the server holds before it pauses reading the socket.
        for seq in range(1, 21):
            await ws.send(
                json.dumps({"op": "update_param", "id": f"u{seq}", "instance_id": iid,
                            "samples": [sample(seq)]})
            )  # fmt: skip
            await ws.send(
                json.dumps({"op": "publish", "id": f"p{seq}", "topic": f"vehicle/{vid}/depth",
                            "data": {"seq": seq}})
            )  # fmt: skip
        got = await acks(ws, 40)
        assert [i for i, _ in got] == [f"{k}{n}" for n in range(1, 21) for k in "up"]
        assert all(ok for _, ok in got)
    r = await api.get(f"/api/vehicles/{vid}/telemetry", headers=ADMIN)
    assert [s["seq"] for s in r.json()["samples"]] == list(range(1, 21))


async def test_messages_sent_while_the_token_is_checked_are_all_handled(
    base: str, api: httpx.AsyncClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    name, user = await make_user(api, "viewer", [])
    gate = asyncio.Event()
    authenticate = AuthService.authenticate

    async def held(self: AuthService, token: str | None) -> Any:
        await gate.wait()
        return await authenticate(self, token)

    monkeypatch.setattr(AuthService, "authenticate", held)
    async with await connect(base, "/ws/client", tok(user)) as ws:
        for n in range(3):  # the socket is open, its token not checked yet
            frame = {"op": "publish", "id": str(n), "topic": f"user/{name}/x", "data": n}
            await ws.send(json.dumps(frame))
        await asyncio.sleep(0)  # not a wait for the server: the gate holds it
        gate.set()
        assert await acks(ws, 3) == [("0", True), ("1", True), ("2", True)]


async def test_a_fault_closes_that_socket_alone_with_1011(
    base: str, api: httpx.AsyncClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    name, user = await make_user(api, "viewer", [])
    text_now = OpRunner.text_now

    def faulty(self: OpRunner, frame: str, **kwargs: Any) -> Any:
        if "boom" in frame:
            raise ValueError("a bug")
        return text_now(self, frame, **kwargs)

    monkeypatch.setattr(OpRunner, "text_now", faulty)
    async with (
        await connect(base, "/ws/client", tok(user)) as ws,
        await connect(base, "/ws/client", tok(user)) as bystander,
    ):
        await ws.send(json.dumps({"op": "publish", "topic": f"user/{name}/boom", "data": 0}))
        with pytest.raises(websockets.ConnectionClosed) as closed:
            await recv_json(ws)
        assert closed.value.rcvd is not None and closed.value.rcvd.code == 1011
        ack = await call(bystander, "publish", "b", topic=f"user/{name}/fine", data=1)
        assert ack["ok"] is True
