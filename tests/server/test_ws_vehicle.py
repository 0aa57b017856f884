"""/ws/vehicle end to end: real uvicorn, real websockets clients (a gateway's batches:
test_ws_gateway_batch.py)."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Callable

import httpx
import pytest
import websockets

from server.settings import Settings
from tests.factories import ADMIN, ADMIN_TOKEN, make_user, make_vehicle, sample, start_instance
from tests.live import call, connect, recv_json, recv_until, serve, ws_url

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")

CAPS = ["stop", "go_to", "keep_station", "follow_path"]


def token_of(headers: dict[str, str]) -> str:
    return headers["Authorization"].removeprefix("Bearer ")


async def _close_code(ws: websockets.ClientConnection) -> int | None:
    with pytest.raises(websockets.ConnectionClosed):
        await recv_until(ws, lambda f: False, within_s=10)
    return ws.close_code


async def test_no_token_closes_4401(base: str) -> None:
    """Without a token the first frame must be ``auth``: anything else closes it."""
    async with websockets.connect(ws_url(base, "/ws/vehicle")) as ws:
        await ws.send(json.dumps({"op": "heartbeat", "id": "h", "instance_id": "i-1"}))
        assert await _close_code(ws) == 4401


async def test_bad_token_in_query_closes_4401(base: str) -> None:
    async with websockets.connect(ws_url(base, "/ws/client", "fct_nope")) as ws:
        assert await _close_code(ws) == 4401


async def test_wrong_kind_of_token_closes_4403(base: str, api: httpx.AsyncClient) -> None:
    _, vh = await make_vehicle(api)
    async with await connect(base, "/ws/client", token_of(vh)) as ws:
        assert await _close_code(ws) == 4403
    async with await connect(base, "/ws/vehicle", ADMIN_TOKEN) as ws:
        assert await _close_code(ws) == 4403


async def _start(ws: websockets.ClientConnection, vehicle_id: str) -> str:
    ack = await call(
        ws,
        "start_instance",
        "s1",
        vehicle_id=vehicle_id,
        name=vehicle_id,
        vehicle_type="usv",
        capabilities=CAPS,
    )
    assert ack["ok"] is True, ack
    return str(ack["instance_id"])


async def _lease(api: httpx.AsyncClient, vehicle_id: str, iid: str) -> dict[str, str]:
    user, op = await make_user(api, "operator", [vehicle_id])
    r = await api.post(
        "/client/grant_control",
        headers=ADMIN,
        json={"instance_id": iid, "user": user, "duration_s": 600},
    )
    assert r.status_code == 200, r.text
    return op


async def test_command_is_pushed_at_once_and_acked(base: str, api: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(api)
    async with await connect(base, "/ws/vehicle", token_of(vh)) as ws:
        iid = await _start(ws, vid)
        op = await _lease(api, vid, iid)
        control = await recv_until(ws, lambda f: f["op"] == "control" and f["control"])
        assert control["instance_id"] == iid and control["control"]["holder"]
        r = await api.post(
            "/client/submit_control",
            headers=op,
            json={
                "instance_ids": [iid],
                "command": {"type": "go_to", "args": {"lat": 43.95, "lon": 15.45}},
            },
        )
        assert r.status_code == 202, r.text
        command_id = r.json()["commands"][0]["command_id"]
        pushed = await recv_until(ws, lambda f: f["op"] == "command")
        assert pushed["command_id"] == command_id and pushed["type"] == "go_to"
        assert pushed["status"] == "delivered"
        ack = await call(
            ws,
            "update_fbmessage",
            "f1",
            instance_id=iid,
            control_mode="remote",
            acks=[{"command_id": command_id, "status": "accepted"}],
        )
        assert ack["ok"] is True and ack["abort"] == []
    got = (await api.get(f"/api/commands/{command_id}", headers=ADMIN)).json()
    assert got["status"] == "accepted"


async def test_a_command_cancelled_while_under_way_is_pushed_as_an_abort(
    base: str, api: httpx.AsyncClient
) -> None:
    """Cancelled after the vehicle accepted it: the socket is told at once (``abort``),
    not at the vehicle's next ``update_fbmessage``, which a go_to under way may not send."""
    vid, vh = await make_vehicle(api)
    async with await connect(base, "/ws/vehicle", token_of(vh)) as ws:
        iid = await _start(ws, vid)
        op = await _lease(api, vid, iid)
        body = {
            "instance_ids": [iid],
            "command": {"type": "go_to", "args": {"lat": 43.95, "lon": 15.45}},
        }
        r = await api.post("/client/submit_control", headers=op, json=body)
        command_id = r.json()["commands"][0]["command_id"]
        await recv_until(ws, lambda f: f["op"] == "command")
        acks = [{"command_id": command_id, "status": s} for s in ("accepted", "executing")]
        ack = await call(ws, "update_fbmessage", "f1", instance_id=iid, acks=acks)
        assert ack["ok"] is True and ack["abort"] == []
        r = await api.post("/client/cancel_command", headers=op, json={"command_id": command_id})
        assert r.status_code == 200 and r.json()["status"] == "cancelled", r.text
        told = await recv_until(ws, lambda f: f["op"] == "abort")
        assert told == {"op": "abort", "instance_id": iid, "command_ids": [command_id]}
        # Told once: the next update_fbmessage does not say it again.
        ack = await call(ws, "update_fbmessage", "f2", instance_id=iid, control_mode="idle")
        assert ack["ok"] is True and ack["abort"] == []


async def test_stop_jumps_the_queue_on_the_socket(base: str, api: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(api)
    async with await connect(base, "/ws/vehicle", token_of(vh)) as ws:
        iid = await _start(ws, vid)
        _, anyone = await make_user(api, "operator", [vid])  # no lease: stop is still allowed
        r = await api.post(
            "/client/submit_control",
            headers=anyone,
            json={"instance_ids": ["*"], "command": {"type": "stop"}},
        )
        assert r.status_code == 202, r.text
        pushed = await recv_until(ws, lambda f: f["op"] == "command")
        assert pushed["type"] == "stop" and pushed["instance_id"] == iid


async def test_a_resume_over_the_socket_without_capabilities_keeps_them(
    base: str, api: httpx.AsyncClient
) -> None:
    """``start_instance`` with no ``capabilities`` resumes with those the vehicle gave: a
    ``go_to`` is still taken (not 422 ``capability_missing``)."""
    vid, vh = await make_vehicle(api)
    async with await connect(base, "/ws/vehicle", token_of(vh)) as ws:
        iid = await _start(ws, vid)
        ack = await call(ws, "start_instance", "s2", vehicle_id=vid)
        assert ack["ok"] is True and ack["resumed"] is True and ack["instance_id"] == iid
    r = await api.post("/client/connect_instance", headers=ADMIN, json={"instance_id": iid})
    assert r.json()["instance"]["capabilities"] == CAPS
    lease = await _lease(api, vid, iid)
    r = await api.post(
        "/client/submit_control",
        headers=lease,
        json={
            "instance_ids": [iid],
            "command": {"type": "go_to", "args": {"lat": 43.9, "lon": 15.4}},
        },
    )
    assert r.status_code == 202, r.text


GO = {"type": "go_to", "args": {"lat": 43.9, "lon": 15.4}}


@pytest.mark.parametrize(
    ("op", "fields"),
    [
        ("heartbeat", {}),
        ("update_param", {"params": {"mode": "survey"}}),
        ("update_fbmessage", {"control_mode": "remote"}),
    ],
)
@pytest.mark.parametrize(
    ("queued", "pushed"),
    [([GO, GO, GO], ["go_to"] * 3), ([GO, {"type": "stop"}], ["stop"])],
    ids=["three-go_to", "stop"],
)
async def test_the_first_op_of_a_socket_is_acked_before_what_it_takes_up(
    base: str,
    api: httpx.AsyncClient,
    op: str,
    fields: dict[str, object],
    queued: list[dict[str, object]],
    pushed: list[str],
) -> None:
    """A socket whose first op names the instance (no start on it) takes the instance up:
    the op's ack comes first, then the ``control`` push and the queued commands (a
    ``stop``, which jumps every other waiting frame, does not jump the ack either; it
    cancels the moves queued before it)."""
    vid, vh = await make_vehicle(api)
    iid = (await start_instance(api, vid, vh, capabilities=CAPS))["instance_id"]
    lease = await _lease(api, vid, iid)
    for command in queued:
        r = await api.post(
            "/client/submit_control",
            headers=lease,
            json={"instance_ids": [iid], "command": command, "ttl_s": 600},
        )
        assert r.status_code == 202, r.text
    async with await connect(base, "/ws/vehicle", token_of(vh)) as ws:
        await ws.send(json.dumps({"op": op, "id": "x", "instance_id": iid, **fields}))
        frames = [await recv_json(ws) for _ in range(2 + len(pushed))]
    assert [f["op"] for f in frames] == ["ack", "control"] + ["command"] * len(pushed), frames
    assert frames[0]["id"] == "x" and frames[0]["ok"] is True, frames[0]
    assert [f["type"] for f in frames[2:]] == pushed


async def test_telemetry_over_the_socket_is_stored(base: str, api: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(api)
    async with await connect(base, "/ws/vehicle", token_of(vh)) as ws:
        iid = await _start(ws, vid)
        ack = await call(
            ws,
            "update_param",
            "u1",
            instance_id=iid,
            params={"mode": "survey"},
            samples=[sample(1), sample(2), sample(3)],
        )
        assert ack["ok"] is True and ack["accepted"] == 3 and ack["acked_through_seq"] == 3
        dup = await call(ws, "update_param", "u2", instance_id=iid, samples=[sample(3)])
        assert dup["accepted"] == 0 and dup["duplicates"] == 1
    params = (await api.get("/client/get_param", headers=ADMIN, params={"instance_id": iid})).json()
    assert params["params"] == {"mode": "survey"} and params["position"]["seq"] == 3


async def test_an_update_with_only_fields_it_does_not_know_is_refused_naming_the_field(
    base: str, api: httpx.AsyncClient
) -> None:
    """As over HTTP: ``sample`` for ``samples`` is refused naming the field, not acked
    "0 accepted"; unknown fields beside known ones are ignored; an empty update is acked."""
    vid, vh = await make_vehicle(api)
    async with await connect(base, "/ws/vehicle", token_of(vh)) as ws:
        iid = await _start(ws, vid)
        typo = await call(ws, "update_param", "u1", instance_id=iid, sample=[sample(1)])
        assert typo["ok"] is False and typo["error"]["code"] == "invalid", typo
        assert typo["error"]["details"][0]["field"] == "sample", typo
        assert "did you mean samples" in typo["error"]["message"], typo
        newer = await call(
            ws, "update_param", "u2", instance_id=iid, samples=[sample(1)], priority="high"
        )
        assert newer["ok"] is True and newer["accepted"] == 1, newer
        empty = await call(ws, "update_param", "u3", instance_id=iid)
        assert empty["ok"] is True and empty["accepted"] == 0, empty
        newer_empty = await call(
            ws, "update_param", "u4", instance_id=iid, samples=[], battery_summary={}
        )
        assert newer_empty["ok"] is True and newer_empty["accepted"] == 0, newer_empty


async def test_bad_op_is_answered_not_fatal(base: str, api: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(api)
    async with await connect(base, "/ws/vehicle", token_of(vh)) as ws:
        await ws.send("{not json")
        err = await recv_until(ws, lambda f: f["op"] == "error")
        assert err["error"]["code"] == "invalid"
        await ws.send(json.dumps({"op": "launch_missiles", "id": "x1"}))
        nack = await recv_until(ws, lambda f: f["op"] == "ack")
        assert nack["id"] == "x1" and nack["ok"] is False
        assert nack["error"]["details"][0]["field"] == "op"
        other = await call(ws, "heartbeat", "h1", instance_id="i-unknown")
        assert other["ok"] is False and other["error"]["code"] == "not_found"
        iid = await _start(ws, vid)  # the socket still works
        assert iid


async def test_second_socket_replaces_the_first(base: str, api: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(api)
    async with await connect(base, "/ws/vehicle", token_of(vh)) as first:
        await _start(first, vid)
        async with await connect(base, "/ws/vehicle", token_of(vh)) as second:
            await _start(second, vid)
            assert await _close_code(first) == 4409


async def test_revoked_token_closes_the_open_socket(base: str, api: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(api)
    async with await connect(base, "/ws/vehicle", token_of(vh)) as ws:
        await _start(ws, vid)
        r = await api.post(f"/api/vehicles/{vid}/rotate_token", headers=ADMIN)
        assert r.status_code == 200
        assert await _close_code(ws) == 4401


GARBAGE_FRAMES = [
    "",
    "null",
    "[]",
    "42",
    '"op"',
    "{}",
    '{"op": null}',
    '{"op": "batch", "ops": "x"}',
    '{"op": "batch", "id": "b", "ops": [{"op": "batch", "ops": []}]}',
    '{"op": "update_param", "id": "' + "x" * 100 + '"}',
    '{"op": "update_param", "id": "u", "instance_id": {"$gt": ""}, "samples": [{}]}',
    '{"op": "subscribe", "id": "s", "topics": ["a//b", "UPPER", "' + "a/" * 20 + 'a"]}',
    '{"op": "publish", "id": "p", "topic": "fleet", "data": 1}',
    '{"op": "register", "id": "r", "topics": ["vehicle/someone-else/x"]}',
    '{"op": "update_fbmessage", "id": "f", "instance_id": "i-x", "acks": [{"status": "won"}]}',
    '{"op": "heartbeat", "id": 7, "instance_id": 5}',
]


async def test_garbage_frames_are_answered_and_the_socket_survives(
    base: str, api: httpx.AsyncClient
) -> None:
    vid, vh = await make_vehicle(api)
    async with await connect(base, "/ws/vehicle", token_of(vh)) as ws:
        for frame in GARBAGE_FRAMES:
            await ws.send(frame)
            reply = await recv_until(ws, lambda f: f["op"] in ("ack", "error"))
            assert reply.get("ok") is not True, (frame, reply)
            assert reply["error"]["code"] in ("invalid", "forbidden", "not_found"), reply
        await ws.send(b"\x00\x01 not a media frame")
        reply = await recv_until(ws, lambda f: f["op"] == "error")
        assert reply["error"]["code"] == "invalid"
        assert await _start(ws, vid)  # still serving


async def test_a_vehicles_pings_keep_it_online(
    make_settings: Callable[..., Settings],
) -> None:
    """API.md: last_seen moves on every WebSocket frame, pings included. A vehicle whose
    client keeps its socket alive by pings alone stays online (it went stale, then
    offline)."""
    async with serve(make_settings(stale_after_s=1, offline_after_s=2)) as base:
        async with httpx.AsyncClient(base_url=base, timeout=10) as api:
            vid, headers = await make_vehicle(api)
            token = headers["Authorization"].removeprefix("Bearer ")
            async with await connect(base, "/ws/vehicle", token) as ws:
                ack = await call(ws, "start_instance", "s", vehicle_id=vid, capabilities=["stop"])
                assert ack["ok"] is True, ack
                loop = asyncio.get_running_loop()
                until = loop.time() + 3.0  # past offline_after_s, by pings alone
                while loop.time() < until:
                    await (await ws.ping())  # the pong: the ping was read
                    await asyncio.sleep(0.25)  # the client's ping interval, not a wait
                    view = (await api.get(f"/api/vehicles/{vid}", headers=ADMIN)).json()
                    assert view["presence"] == "online", view
            # A socket opened again (after a link loss, say) that has not named the
            # instance yet: its pings are the vehicle's contact all the same.
            async with await connect(base, "/ws/vehicle", token) as ws:
                until = loop.time() + 3.0
                while loop.time() < until:
                    await (await ws.ping())
                    await asyncio.sleep(0.25)
                    view = (await api.get(f"/api/vehicles/{vid}", headers=ADMIN)).json()
                    assert view["presence"] == "online", view
