"""/ws/client end to end: live view, topics across units, backpressure, media."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator, Callable
from datetime import UTC, datetime

import httpx
import pytest
import websockets

from fleet_protocol.media import MediaHeader, decode_media_frame, encode_media_frame
from server.settings import Settings
from tests.factories import ADMIN, make_user, make_vehicle, sample
from tests.live import call, connect, recv_until, serve, ws_url

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")

CAPS = ["stop", "go_to", "keep_station", "follow_path"]


@pytest.fixture
async def base(make_settings: Callable[..., Settings]) -> AsyncIterator[str]:
    async with serve(make_settings(ws_queue_size=16)) as url:
        yield url


@pytest.fixture
async def api(base: str) -> AsyncIterator[httpx.AsyncClient]:
    async with httpx.AsyncClient(base_url=base, timeout=10) as c:
        yield c


def tok(headers: dict[str, str]) -> str:
    return headers["Authorization"].removeprefix("Bearer ")


async def _vehicle_with_instance(api: httpx.AsyncClient) -> tuple[str, dict[str, str], str]:
    vid, vh = await make_vehicle(api)
    r = await api.post(
        "/upper/start_instance", headers=vh, json={"vehicle_id": vid, "capabilities": CAPS}
    )
    return vid, vh, r.json()["instance_id"]


async def test_telemetry_snapshot_then_live_samples(base: str, api: httpx.AsyncClient) -> None:
    vid, vh, iid = await _vehicle_with_instance(api)
    await api.post(
        "/upper/update_param",
        headers=vh,
        json={"instance_id": iid, "samples": [sample(1, lat=43.9001)]},
    )
    _, viewer = await make_user(api, "viewer", [vid])
    async with await connect(base, "/ws/client", tok(viewer)) as ws:
        ack = await call(ws, "subscribe", "s", topics=[f"vehicle/{vid}/telemetry"])
        assert ack["ok"] is True
        snap = await recv_until(ws, lambda f: f["op"] == "event")
        assert snap["snapshot"] is True and snap["data"]["seq"] == 1
        await api.post(
            "/upper/update_param",
            headers=vh,
            json={"instance_id": iid, "samples": [sample(2, lat=43.9002)]},
        )
        live = await recv_until(ws, lambda f: f["op"] == "event")
        assert "snapshot" not in live
        assert live["topic"] == f"vehicle/{vid}/telemetry" and live["data"]["seq"] == 2
        assert live["data"]["lat"] == 43.9002


async def test_throttle_gives_the_first_sample_then_the_latest_once_due(
    base: str, api: httpx.AsyncClient
) -> None:
    vid, vh, iid = await _vehicle_with_instance(api)
    _, viewer = await make_user(api, "viewer", [vid])
    async with await connect(base, "/ws/client", tok(viewer)) as ws:
        topic = f"vehicle/{vid}/telemetry"
        ack = await call(ws, "subscribe", "s", topics=[topic], throttle_ms=400)
        assert ack["ok"] is True
        for seq in range(1, 6):  # a burst well inside one interval
            r = await api.post(
                "/upper/update_param",
                headers=vh,
                json={"instance_id": iid, "samples": [sample(seq, lat=43.9 + seq / 1e4)]},
            )
            assert r.status_code == 200, r.text
        first = await recv_until(ws, lambda f: f["op"] == "event")
        assert first["data"]["seq"] == 1
        # Nothing more is sent: the latest value still arrives once the interval is over.
        latest = await recv_until(ws, lambda f: f["op"] == "event", within_s=5)
        assert latest["data"]["seq"] == 5


async def test_fleet_shows_only_visible_vehicles(base: str, api: httpx.AsyncClient) -> None:
    v1, h1, i1 = await _vehicle_with_instance(api)
    v2, _, _ = await _vehicle_with_instance(api)
    _, viewer = await make_user(api, "viewer", [v1])
    async with await connect(base, "/ws/client", tok(viewer)) as ws:
        await call(ws, "subscribe", "s", topics=["fleet"])
        snap = await recv_until(ws, lambda f: f["op"] == "event")
        assert [v["vehicle_id"] for v in snap["data"]["vehicles"]] == [v1]
        await api.post("/upper/finish_instance", headers=h1, json={"instance_id": i1})
        change = await recv_until(ws, lambda f: f["op"] == "event")
        assert change["data"]["vehicles"][0]["vehicle_id"] == v1
        assert change["data"]["vehicles"][0]["presence"] == "finished"
        assert v2 not in json.dumps(change)


async def test_fleet_tells_of_a_vehicle_starting_a_new_instance(
    base: str, api: httpx.AsyncClient
) -> None:
    """A vehicle's first start, and its start after a finish, are presence changes: a
    fleet watcher hears of them (it saw the vehicle offline, or finished, for good)."""
    vid, vh = await make_vehicle(api)
    _, viewer = await make_user(api, "viewer", [vid])
    async with await connect(base, "/ws/client", tok(viewer)) as ws:
        await call(ws, "subscribe", "s", topics=["fleet"])
        snap = await recv_until(ws, lambda f: f["op"] == "event")
        assert snap["data"]["vehicles"][0]["presence"] == "offline"
        for name in ("First", "Second"):
            r = await api.post(
                "/upper/start_instance", headers=vh, json={"vehicle_id": vid, "name": name}
            )
            assert r.status_code == 200, r.text
            iid = r.json()["instance_id"]
            change = await recv_until(ws, lambda f: f["op"] == "event", within_s=2)
            (view,) = change["data"]["vehicles"]
            assert (view["vehicle_id"], view["instance_id"]) == (vid, iid)
            assert (view["presence"], view["name"]) == ("online", name)
            await api.post("/upper/finish_instance", headers=vh, json={"instance_id": iid})
            done = await recv_until(ws, lambda f: f["op"] == "event")
            assert done["data"]["vehicles"][0]["presence"] == "finished"


async def test_an_auth_op_on_a_socket_that_has_its_token_says_so(
    base: str, api: httpx.AsyncClient
) -> None:
    """``auth`` is a documented op (the first frame, when no header carried the token): sent
    again, or beside a header, it is refused as such, not as an op the socket does not
    know (its list of ops leaves ``auth`` out); the socket goes on."""
    _, viewer = await make_user(api, "viewer", [])
    token = tok(viewer)
    async with await connect(base, "/ws/client", token) as with_header:
        said = await call(with_header, "auth", "a", token=token)
        assert said["ok"] is False and said["error"]["code"] == "invalid"
        (detail,) = said["error"]["details"]
        assert detail["field"] == "op" and "first frame only" in detail["message"]
        assert "unknown op" not in said["error"]["message"]
        assert (await call(with_header, "subscribe", "s", topics=["fleet"]))["ok"] is True
    async with websockets.connect(ws_url(base, "/ws/client"), compression=None) as bare:
        assert (await call(bare, "auth", "a1", token=token))["ok"] is True
        again = await call(bare, "auth", "a2", token=token)
        assert again["ok"] is False and "first frame only" in again["error"]["message"]


async def test_fleet_tells_of_a_vehicle_resuming_under_a_new_name(
    base: str, api: httpx.AsyncClient
) -> None:
    """An agent restarted with a new name resumes its instance: watchers kept the old name
    until the vehicle's next presence change."""
    vid, vh = await make_vehicle(api)
    _, viewer = await make_user(api, "viewer", [vid])
    first = {"vehicle_id": vid, "name": "Before"}
    r = await api.post("/upper/start_instance", headers=vh, json=first)
    assert r.status_code == 200, r.text
    async with await connect(base, "/ws/client", tok(viewer)) as ws:
        await call(ws, "subscribe", "s", topics=["fleet"])
        snap = await recv_until(ws, lambda f: f["op"] == "event")
        assert snap["data"]["vehicles"][0]["name"] == "Before"
        again = {"vehicle_id": vid, "name": "After", "vehicle_type": "auv"}
        r = await api.post("/upper/start_instance", headers=vh, json=again)
        assert r.status_code == 200 and r.json()["resumed"] is True, r.text
        change = await recv_until(ws, lambda f: f["op"] == "event")
        (view,) = change["data"]["vehicles"]
        assert (view["name"], view["vehicle_type"], view["presence"]) == ("After", "auv", "online")


async def test_reading_another_vehicle_is_refused(base: str, api: httpx.AsyncClient) -> None:
    v1, _, _ = await _vehicle_with_instance(api)
    v2, _, _ = await _vehicle_with_instance(api)
    _, viewer = await make_user(api, "viewer", [v1])
    async with await connect(base, "/ws/client", tok(viewer)) as ws:
        nack = await call(ws, "subscribe", "s", topics=[f"vehicle/{v2}/telemetry"])
        assert nack["ok"] is False and nack["error"]["code"] == "forbidden"
        bad = await call(ws, "subscribe", "t", topics=["Vehicle/#"])
        assert bad["ok"] is False and bad["error"]["code"] == "invalid"


async def test_commands_and_control_topics(base: str, api: httpx.AsyncClient) -> None:
    vid, _, iid = await _vehicle_with_instance(api)
    user, op = await make_user(api, "operator", [vid])
    async with await connect(base, "/ws/client", tok(op)) as ws:
        await call(
            ws, "subscribe", "s", topics=[f"vehicle/{vid}/control", f"vehicle/{vid}/commands"]
        )
        r = await api.post(
            "/client/grant_control",
            headers=ADMIN,
            json={"instance_id": iid, "user": user, "duration_s": 60},
        )
        assert r.status_code == 200
        granted = await recv_until(
            ws, lambda f: f.get("topic", "").endswith("/control") and not f.get("snapshot")
        )
        assert granted["data"]["control"]["holder"] == user
        r = await api.post(
            "/client/submit_control",
            headers=op,
            json={"instance_ids": [iid], "command": {"type": "keep_station", "args": {}}},
        )
        command_id = r.json()["commands"][0]["command_id"]
        seen = await recv_until(
            ws, lambda f: f.get("topic", "").endswith("/commands") and not f.get("snapshot")
        )
        assert seen["data"]["commands"][0]["command_id"] == command_id


async def test_each_step_of_a_command_is_on_its_topic(base: str, api: httpx.AsyncClient) -> None:
    vid, vh, iid = await _vehicle_with_instance(api)
    user, op = await make_user(api, "operator", [vid])
    body = {"instance_id": iid, "user": user, "duration_s": 60}
    assert (await api.post("/client/grant_control", headers=ADMIN, json=body)).status_code == 200
    topic = f"vehicle/{vid}/commands"
    async with await connect(base, "/ws/client", tok(op)) as ws:
        await call(ws, "subscribe", "s", topics=[topic])
        await recv_until(ws, lambda f: f.get("topic") == topic and f.get("snapshot"))
        r = await api.post(
            "/client/submit_control",
            headers=op,
            json={"instance_ids": [iid], "command": {"type": "keep_station", "args": {}}},
        )
        command_id = r.json()["commands"][0]["command_id"]
        r = await api.get("/upper/get_control", headers=vh, params={"instance_id": iid})
        assert [c["command_id"] for c in r.json()["commands"]] == [command_id]
        for status in ("accepted", "executing", "done"):
            ack = {"command_id": command_id, "status": status, "progress": 0.5}
            r = await api.post(
                "/upper/update_fbmessage", headers=vh, json={"instance_id": iid, "acks": [ack]}
            )
            assert r.status_code == 200, r.text
        steps: list[str] = []
        while not steps or steps[-1] != "done":
            event = await recv_until(ws, lambda f: f.get("topic") == topic)
            moved = event["data"]["commands"][0]
            assert moved["command_id"] == command_id
            steps.append(moved["status"])
        assert steps == ["queued", "delivered", "accepted", "executing", "done"]


async def test_units_register_subscribe_and_publish(base: str, api: httpx.AsyncClient) -> None:
    vid, vh, _ = await _vehicle_with_instance(api)
    worker, wh = await make_user(api, "viewer", [vid])
    _, other = await make_user(api, "viewer", [vid])
    topic = f"vehicle/{vid}/sonar_summary"
    async with (
        await connect(base, "/ws/vehicle", tok(vh)) as car,
        await connect(base, "/ws/client", tok(wh)) as w,
        await connect(base, "/ws/client", tok(other)) as bystander,
    ):
        reg = await call(car, "register", "r", topics=[topic])
        assert reg["ok"] is True
        routes = await recv_until(car, lambda f: f["op"] == "routes")
        assert routes["produces"] == {topic: []}
        await call(w, "subscribe", "s", topics=[topic])
        routes = await recv_until(car, lambda f: f["op"] == "routes")
        assert routes["produces"] == {topic: [f"user:{worker}"]}
        await call(car, "publish", "p", topic=topic, data={"depth_m": 12.5})
        got = await recv_until(w, lambda f: f["op"] == "event" and not f.get("snapshot"))
        assert got["data"] == {"depth_m": 12.5} and got["source"] == f"vehicle:{vid}"
        assert set(got) == {"op", "topic", "data", "source", "ts"}  # no routing of our own
        # exactly the subscribers: the bystander hears nothing, the publisher no echo
        results = f"user/{worker}/results/{vid}"  # the worker's results about the vehicle
        refused = await call(bystander, "subscribe", "q0", topics=[f"user/{worker}/results"])
        assert refused["ok"] is False and refused["error"]["code"] == "forbidden"  # its own
        await call(bystander, "subscribe", "q", topics=[results])
        with pytest.raises(TimeoutError):
            await recv_until(
                bystander, lambda f: f["op"] == "event" and not f.get("snapshot"), within_s=0.5
            )
        # namespaces: a user writes only under user/<name>/, never into a vehicle's
        nack = await call(w, "publish", "x", topic=topic, data={})
        assert nack["ok"] is False and nack["error"]["code"] == "forbidden"
        ok = await call(w, "publish", "y", topic=results, data={"n": 1})
        assert ok["ok"] is True
        got = await recv_until(bystander, lambda f: f["op"] == "event" and not f.get("snapshot"))
        assert got["data"] == {"n": 1}


async def test_slow_subscriber_is_told_it_lags(base: str, api: httpx.AsyncClient) -> None:
    _, wh = await make_user(api, "viewer")
    name = (await api.get("/api/users", headers=ADMIN)).json()["users"][-1]["username"]
    topic = f"user/{name}/bulk"
    async with (
        await connect(base, "/ws/client", tok(wh)) as pub,
        await connect(base, "/ws/client", tok(wh)) as slow,
    ):
        await call(slow, "subscribe", "s", topics=[topic])
        blob = "x" * 60_000
        for i in range(300):  # ~18 MB: more than the socket buffers hold
            await pub.send(json.dumps({"op": "publish", "topic": topic, "data": [i, blob]}))
        lag = await recv_until(slow, lambda f: f["op"] == "lagging", within_s=30)
        assert lag["dropped"] >= 1


async def test_media_frames_are_binary_and_latest_wins(base: str, api: httpx.AsyncClient) -> None:
    vid, vh, _ = await _vehicle_with_instance(api)
    _, viewer = await make_user(api, "viewer", [vid])
    topic = f"vehicle/{vid}/camera"
    async with (
        await connect(base, "/ws/vehicle", tok(vh)) as car,
        await connect(base, "/ws/client", tok(viewer)) as ws,
    ):
        await call(ws, "subscribe", "s", topics=[topic])
        header = MediaHeader(topic=topic, ts=datetime.now(UTC), content_type="image/jpeg")
        await car.send(encode_media_frame(header, b"\xff\xd8jpeg-bytes"))
        frame = await asyncio.wait_for(ws.recv(), 10)
        while isinstance(frame, str):  # skip the ack
            frame = await asyncio.wait_for(ws.recv(), 10)
        got, payload = decode_media_frame(frame)
        assert got.topic == topic and payload == b"\xff\xd8jpeg-bytes"
        wrong = MediaHeader(
            topic=f"vehicle/{vid}/notes", ts=datetime.now(UTC), content_type="text/plain"
        )
        await car.send(encode_media_frame(wrong, b"hi"))
        err = await recv_until(car, lambda f: f["op"] == "error")
        assert err["error"]["code"] == "invalid"


async def test_a_publish_says_its_data_and_sends_json_only_where_json_goes(
    base: str, api: httpx.AsyncClient
) -> None:
    """``data`` is required (``null`` said, not left out); a media topic takes binary
    frames only; ``fleet`` is one topic, nothing under it."""
    vid, vh, _ = await _vehicle_with_instance(api)
    _, uh = await make_user(api, "viewer", [vid])
    async with (
        await connect(base, "/ws/vehicle", tok(vh)) as car,
        await connect(base, "/ws/client", tok(uh)) as user,
    ):
        topic = f"vehicle/{vid}/sonar_summary"
        missing = await call(car, "publish", "p1", topic=topic)
        assert missing["ok"] is False
        assert [d["field"] for d in missing["error"]["details"]] == ["data"]
        said = await call(car, "publish", "p2", topic=topic, data=None)
        assert said["ok"] is True
        camera = await call(car, "publish", "p3", topic=f"vehicle/{vid}/camera/front", data=1)
        assert camera["ok"] is False and "binary frames" in camera["error"]["message"]
        assert [d["field"] for d in camera["error"]["details"]] == ["topic"]
        under = await call(user, "subscribe", "s", topics=["fleet/x"])
        assert under["ok"] is False and "no topics under 'fleet/'" in under["error"]["message"]
        assert (await call(user, "subscribe", "s2", topics=["fleet"]))["ok"] is True
