"""Values JSON or the store cannot hold stop at the edge with a 422 naming the field, on HTTP
and on the WebSocket alike; what was stored before a rule existed is still served, escaped."""

from __future__ import annotations

import asyncio
import json
import math
from collections.abc import AsyncIterator, Callable
from datetime import UTC, datetime
from typing import Any

import httpx
import pytest
from asgi_lifespan import LifespanManager

from fleet_protocol import MAX_JSON_DEPTH, EventPush, TelemetryPage, parse_ts
from server.api.responses import ModelResponse, SafeJSONResponse
from server.app import create_app
from server.bus.wire import dumps
from server.settings import Settings
from tests.factories import ADMIN, make_vehicle, sample, start_instance
from tests.live import call, connect, recv_until, serve

# Each test on the embedded store and on FerretDB: what reaches the store is what it holds.
pytestmark = pytest.mark.usefixtures("store_backend")

DEADLINE_S = 15.0


def strict_loads(text: str | bytes) -> Any:
    """JSON as a strict reader takes it: UTF-8 without lone surrogates, no NaN tokens."""

    def no_constants(token: str) -> Any:
        raise AssertionError(f"{token} is not JSON")

    if isinstance(text, str):
        text = text.encode("utf-8")  # a lone surrogate fails here
    return json.loads(text.decode("utf-8"), parse_constant=no_constants)


async def strict_reply(ws: Any, op_id: str) -> dict[str, Any]:
    """The frame answering ``op_id``; every frame up to it must be strict JSON."""
    async with asyncio.timeout(10):
        while True:
            frame = strict_loads(await ws.recv())
            if frame.get("id") == op_id:
                return frame  # type: ignore[no-any-return]


def token_of(headers: dict[str, str]) -> str:
    return headers["Authorization"].removeprefix("Bearer ")


@pytest.fixture
async def durable_client(
    make_settings: Callable[..., Settings],
) -> AsyncIterator[httpx.AsyncClient]:
    """An app that stores every sample in a bucket of its own (durable soon after)."""
    app = create_app(make_settings(bucket_samples=1))
    async with LifespanManager(app) as manager:
        transport = httpx.ASGITransport(app=manager.app)
        async with httpx.AsyncClient(transport=transport, base_url="http://test") as c:
            c.app = app  # type: ignore[attr-defined]
            yield c


@pytest.fixture
async def base(make_settings: Callable[..., Settings]) -> AsyncIterator[str]:
    async with serve(make_settings(bucket_samples=1)) as url:
        yield url


def with_data(raw_data: str, seq: int = 1, **fields: Any) -> str:
    """An update_param body whose first sample's ``data`` is ``raw_data`` written verbatim
    (JSON text that json.dumps would not write: NaN tokens, lone surrogate escapes)."""
    body = {**fields, "samples": [sample(seq, data="@DATA@")]}
    return json.dumps(body).replace('"@DATA@"', raw_data)


def fields_of(answer: dict[str, Any]) -> list[str]:
    return [d["field"] for d in answer["error"]["details"]]


async def post_update(
    client: httpx.AsyncClient, vh: dict[str, str], content: str
) -> httpx.Response:
    headers = {**vh, "content-type": "application/json"}
    return await client.post("/upper/update_param", headers=headers, content=content)


async def durable_through(
    client: httpx.AsyncClient, vh: dict[str, str], iid: str, seq: int
) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + DEADLINE_S
    while True:
        r = await client.post("/upper/update_param", headers=vh, json={"instance_id": iid})
        assert r.status_code == 200, r.text
        if r.json()["durable_through_seq"] >= seq:
            return
        if loop.time() > deadline:
            raise AssertionError(f"seq {seq} not durable: {r.json()}")
        await asyncio.sleep(0.05)


# -- the regression: a 2^63 reading ------------------------------------------


async def test_a_2_to_the_63_reading_over_http_is_422_and_the_next_good_one_is_durable(
    durable_client: httpx.AsyncClient,
) -> None:
    vid, vh = await make_vehicle(durable_client)
    iid = (await start_instance(durable_client, vid, vh))["instance_id"]
    r = await durable_client.post(
        "/upper/update_param",
        headers=vh,
        json={"instance_id": iid, "samples": [sample(1, data={"big": 2**63})]},
    )
    assert r.status_code == 422, r.text
    assert r.json()["error"]["code"] == "invalid"
    assert fields_of(r.json()) == ["samples.0.data.big"]
    r = await durable_client.post(
        "/upper/update_param",
        headers=vh,
        json={"instance_id": iid, "samples": [sample(1, data={"big": 2**63 - 1})]},
    )
    assert r.status_code == 200 and r.json()["accepted"] == 1, r.text
    await durable_through(durable_client, vh, iid, 1)
    r = await durable_client.get(f"/api/vehicles/{vid}/telemetry", headers=ADMIN)
    assert [s["data"] for s in r.json()["samples"]] == [{"big": 2**63 - 1}]


async def test_a_2_to_the_63_reading_over_the_socket_is_refused_and_the_next_good_one_is_durable(
    base: str,
) -> None:
    async with httpx.AsyncClient(base_url=base, timeout=10) as api:
        vid, vh = await make_vehicle(api)
        async with await connect(base, "/ws/vehicle", token_of(vh)) as ws:
            start = await call(ws, "start_instance", "s", vehicle_id=vid, capabilities=["stop"])
            iid = start["instance_id"]
            bad = [sample(1, data={"big": 2**63})]
            nack = await call(ws, "update_param", "u1", instance_id=iid, samples=bad)
            assert nack["ok"] is False and nack["error"]["code"] == "invalid"
            assert fields_of(nack) == ["samples.0.data.big"]
            await ws.send(json.dumps({"op": "update_param", "instance_id": iid, "samples": bad}))
            pushed = await recv_until(ws, lambda f: f["op"] == "error")
            assert fields_of(pushed) == ["samples.0.data.big"]
            good = [sample(1, data={"big": 2**63 - 1})]
            ack = await call(ws, "update_param", "u2", instance_id=iid, samples=good)
            assert ack["ok"] is True and ack["accepted"] == 1, ack
            loop = asyncio.get_running_loop()
            deadline = loop.time() + DEADLINE_S
            n = 0
            while ack["durable_through_seq"] < 1:
                assert loop.time() < deadline, ack
                await asyncio.sleep(0.05)
                n += 1
                ack = await call(ws, "update_param", f"d{n}", instance_id=iid)
        r = await api.get(f"/api/vehicles/{vid}/telemetry", headers=ADMIN)
        assert [s["data"] for s in r.json()["samples"]] == [{"big": 2**63 - 1}]


# -- one case per rule, over HTTP and over the socket ---------------------------

DEEP = "[" * MAX_JSON_DEPTH + "1" + "]" * MAX_JSON_DEPTH  # under data: one level too many

RULES = [  # (id, the raw data, the field named)
    ("int-over", json.dumps({"x": 2**63}), "samples.0.data.x"),
    ("int-under", json.dumps({"x": -(2**63) - 1}), "samples.0.data.x"),
    ("nan", '{"x": NaN}', "samples.0.data.x"),
    ("infinity", '{"x": [1, Infinity]}', "samples.0.data.x.1"),
    ("minus-infinity", '{"x": {"y": -Infinity}}', "samples.0.data.x.y"),
    ("surrogate-in-value", '{"x": "a\\ud800"}', "samples.0.data.x"),
    ("surrogate-in-key", '{"k\\udc00": 1}', "samples.0.data.k\ufffd"),
    ("dollar-key", '{"$where": 1}', "samples.0.data.$where"),
    ("dot-key", '{"a": {"b.c": 1}}', "samples.0.data.a.b.c"),
    ("nul-key", '{"a\\u0000b": 1}', "samples.0.data.a\x00b"),
    ("too-deep", '{"x": ' + DEEP + "}", "samples.0.data.x" + ".0" * (MAX_JSON_DEPTH - 1)),
    # past the 4,300 digits Python's json reads: named as any other, not "not valid JSON"
    ("int-4301-digits", '{"x": ' + "1" * 4301 + "}", "samples.0.data.x"),
    ("int-minus-100k-digits", '{"x": [0, -' + "9" * 100_000 + "]}", "samples.0.data.x.1"),
]


@pytest.mark.parametrize(("raw", "field"), [r[1:] for r in RULES], ids=[r[0] for r in RULES])
async def test_each_rule_over_http(client: httpx.AsyncClient, raw: str, field: str) -> None:
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    r = await post_update(client, vh, with_data(raw, instance_id=iid))
    assert r.status_code == 422, r.text
    answer = strict_loads(r.content)
    assert answer["error"]["code"] == "invalid"
    assert fields_of(answer) == [field]


@pytest.mark.parametrize(("raw", "field"), [r[1:] for r in RULES], ids=[r[0] for r in RULES])
async def test_each_rule_over_the_socket(base: str, raw: str, field: str) -> None:
    async with httpx.AsyncClient(base_url=base, timeout=10) as api:
        vid, vh = await make_vehicle(api)
    async with await connect(base, "/ws/vehicle", token_of(vh)) as ws:
        start = await call(ws, "start_instance", "s", vehicle_id=vid, capabilities=["stop"])
        await ws.send(with_data(raw, op="update_param", id="u", instance_id=start["instance_id"]))
        nack = await strict_reply(ws, "u")
        assert (nack["op"], nack["ok"]) == ("ack", False), nack
        assert fields_of(nack) == [field]
        assert (await call(ws, "heartbeat", "h", instance_id=start["instance_id"]))["ok"]


async def test_an_integer_too_long_to_read_is_named_wherever_it_is(
    client: httpx.AsyncClient,
) -> None:
    """An integer past Python's 4,300 digits, in a parameter, a route's own field, a body
    sent chunked: 422 naming it and saying why, as a shorter one (not "not valid JSON")."""
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    for digits in (4300, 4301, 50_000):
        content = json.dumps({"instance_id": iid, "params": {"x": "@"}}).replace(
            '"@"', "1" * digits
        )
        r = await post_update(client, vh, content)
        assert r.status_code == 422, r.text
        assert fields_of(r.json()) == ["params.x"], r.text
        assert "within signed 64-bit" in r.json()["error"]["details"][0]["message"]
    big = "9" * 5000
    r = await client.post(
        "/api/zones",
        headers={**ADMIN, "content-type": "application/json"},
        content=json.dumps({"name": "a", "kind": "no_go", "clearance_m": "@"}).replace('"@"', big),
    )
    assert r.status_code == 422 and fields_of(r.json()) == ["clearance_m"], r.text
    r = await client.post(  # read by pydantic's parser, not Python's json
        "/auth/token",
        headers={"content-type": "application/json"},
        content=json.dumps({"username": "a", "password": "@"}).replace('"@"', big),
    )
    assert r.status_code == 422 and fields_of(r.json()) == ["password"], r.text

    async def chunked() -> AsyncIterator[bytes]:
        yield b'{"instance_id": "%s", "samples": [{"seq": ' % iid.encode()
        yield big.encode() + b"}]}"

    r = await client.post(
        "/upper/update_param", headers={**vh, "content-type": "application/json"}, content=chunked()
    )
    assert r.status_code == 422 and fields_of(r.json()) == ["samples.0.seq"], r.text
    r = await post_update(client, vh, json.dumps({"instance_id": iid})[:-1] + ', "x": ' + big)
    assert r.status_code == 422, r.text  # not JSON either way, and its number too long
    assert fields_of(r.json()) == ["body"]
    assert "an integer of more than 4,300 digits" in r.json()["error"]["message"]


async def test_a_year_1_timestamp_in_a_sample_is_422(client: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    body = {"instance_id": iid, "samples": [sample(1), {**sample(2), "ts": "0001-01-01T00:00:00Z"}]}
    r = await client.post("/upper/update_param", headers=vh, json=body)
    assert r.status_code == 422, r.text
    assert fields_of(r.json()) == ["samples.1.ts"]


@pytest.mark.parametrize("route", ["track", "telemetry"])
@pytest.mark.parametrize("name", ["from", "to"])
async def test_a_year_1_query_bound_is_422_not_500(
    client: httpx.AsyncClient, route: str, name: str
) -> None:
    vid, _ = await make_vehicle(client)
    r = await client.get(
        f"/api/vehicles/{vid}/{route}", headers=ADMIN, params={name: "0001-01-01T00:00:00Z"}
    )
    assert r.status_code == 422, r.text
    assert fields_of(r.json()) == [name]


async def test_a_lone_surrogate_in_a_plain_string_field_is_422(client: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(client)
    content = json.dumps({"vehicle_id": vid, "name": "@"}).replace("@", "\\ud800")
    r = await client.post(
        "/upper/start_instance", headers={**vh, "content-type": "application/json"}, content=content
    )
    assert r.status_code == 422, r.text
    assert fields_of(r.json()) == ["name"]


async def test_params_are_checked_like_data(client: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    r = await post_update(client, vh, json.dumps({"instance_id": iid, "params": {"p": {"$x": 1}}}))
    assert r.status_code == 422 and fields_of(r.json()) == ["params.p.$x"]
    r = await client.post(
        "/upper/start_instance",
        headers={**vh, "content-type": "application/json"},
        content=json.dumps({"vehicle_id": vid, "params": {"gain": "@"}}).replace('"@"', "NaN"),
    )
    assert r.status_code == 422 and fields_of(r.json()) == ["params.gain"]


async def test_publish_data_is_checked_on_the_socket(base: str) -> None:
    async with httpx.AsyncClient(base_url=base, timeout=10) as api:
        vid, vh = await make_vehicle(api)
    async with await connect(base, "/ws/vehicle", token_of(vh)) as ws:
        topic = f"vehicle/{vid}/sensors"
        op = {"op": "publish", "id": "p1", "topic": topic, "data": {"t": "@"}}
        await ws.send(json.dumps(op).replace('"@"', "NaN"))
        nack = await strict_reply(ws, "p1")
        assert nack["ok"] is False and fields_of(nack) == ["data.t"]


# -- the way out: stored values that break a rule are still served ------------

STORED = {
    "big": 2**64,
    "nan": math.nan,
    "inf": math.inf,
    "text": "a\ud800b",
    "k\udfff": 1,
}
ESCAPED = {"big": str(2**64), "nan": None, "inf": None, "text": "a\ufffdb", "k\ufffd": 1}


async def test_stored_values_json_cannot_hold_are_served_escaped_over_http(
    durable_client: httpx.AsyncClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    vid, _ = await make_vehicle(durable_client)
    services = durable_client.app.state.services  # type: ignore[attr-defined]

    async def page(*args: Any, **kwargs: Any) -> tuple[list[dict[str, Any]], int | None]:
        stored = {**sample(1), "data": STORED}
        return [{**stored, "ts": parse_ts(stored["ts"])}], None

    monkeypatch.setattr(services.telemetry, "page", page)
    r = await durable_client.get(f"/api/vehicles/{vid}/telemetry", headers=ADMIN)
    assert r.status_code == 200, r.text
    assert strict_loads(r.content)["samples"][0]["data"] == ESCAPED


async def test_a_stored_position_that_breaks_a_rule_is_served_escaped_not_500(
    durable_client: httpx.AsyncClient,
) -> None:
    """A latest position an older version stored (a year-1 time, data JSON cannot hold) is
    in the vehicle list, its view and get_param, escaped: never a 500."""
    c = durable_client
    vid, vh = await make_vehicle(c)
    iid = (await start_instance(c, vid, vh))["instance_id"]
    services = c.app.state.services  # type: ignore[attr-defined]
    state = services.instances.current_by_id(iid)
    state.position = {
        **sample(7, ts=datetime(1, 1, 1, tzinfo=UTC)),
        "ts": datetime(1, 1, 1, tzinfo=UTC),
        "heading_deg": math.nan,
        "data": STORED,
    }
    for path, params in (
        ("/api/vehicles", None),
        (f"/api/vehicles/{vid}", None),
        ("/client/get_param", {"instance_id": iid}),
    ):
        r = await c.get(path, headers=ADMIN, params=params)
        assert r.status_code == 200, (path, r.text)
        body = strict_loads(r.content)
        position = body.get("position") or next(
            v["position"] for v in body["vehicles"] if v["vehicle_id"] == vid
        )
        assert position["seq"] == 7 and position["data"] == ESCAPED, path
        assert position["ts"].startswith("0001-01-01") and position.get("heading_deg") is None


def test_the_http_encoders_escape_instead_of_failing() -> None:
    assert strict_loads(SafeJSONResponse({"data": STORED}).body) == {"data": ESCAPED}
    page = TelemetryPage(samples=[{"seq": 1, "data": STORED}], next_after_seq=None)
    assert strict_loads(ModelResponse(page).body)["samples"][0]["data"] == ESCAPED
    clean = TelemetryPage(samples=[{"seq": 1}], next_after_seq=2)
    assert ModelResponse(clean).body == clean.model_dump_json().encode()
    push = EventPush(topic="vehicle/usv-1/x", data=STORED)  # a plain Any field
    assert strict_loads(ModelResponse(push).body)["data"] == ESCAPED


def test_the_socket_encoder_escapes_instead_of_failing() -> None:
    message = {"topic": "vehicle/usv-1/telemetry", "data": {**STORED, 5: "five"}}
    assert strict_loads(dumps(message))["data"] == {**ESCAPED, "5": "five"}
    assert dumps({"a": [1, 2.5, None]}) == '{"a":[1,2.5,null]}'  # orjson, the hot path
