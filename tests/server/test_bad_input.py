"""Bad input: 422 naming the field, 413 for over-size, never a 500 — on every route."""

from __future__ import annotations

import json
import random

import httpx
import pytest

from server.app import create_app
from server.settings import Settings
from tests.factories import ADMIN, make_vehicle, start_instance

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")

GARBAGE: list[object] = [
    None,
    0,
    -1,
    1e308,
    "",
    "x" * 5000,
    [],
    [1, "a", None],
    {},
    {"instance_id": None},
    {"instance_id": ["a"]},
    {"vehicle_id": "../../etc"},
    {"samples": "many"},
    {"samples": [{"seq": -5}]},
    {"command": {"type": "launch"}},
    {"instance_ids": [], "command": {}},
    {"ttl_s": 0},
    {"duration_s": 10**12},
    {"username": {"$ne": None}},
    {"params": {"a": float("nan")}} if False else {"params": 5},
]


async def test_422_names_the_fields(client: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    r = await client.post(
        "/upper/update_param",
        headers=vh,
        json={
            "instance_id": iid,
            "samples": [{"seq": 1, "ts": "2026-11-22T10:00:00Z", "lat": 95, "lon": 15}],
        },
    )
    assert r.status_code == 422
    err = r.json()["error"]
    assert err["code"] == "invalid"
    assert err["details"] == [{"field": "samples.0.lat", "message": err["details"][0]["message"]}]


async def test_malformed_json_is_422(client: httpx.AsyncClient) -> None:
    r = await client.post(
        "/api/vehicles", headers={**ADMIN, "content-type": "application/json"}, content=b"{not json"
    )
    assert r.status_code == 422
    assert r.json()["error"]["code"] == "invalid"


async def test_every_unreadable_body_is_422_naming_body_and_saying_why(
    client: httpx.AsyncClient,
) -> None:
    """Not JSON, not UTF-8, nested past what a JSON reader goes: the same 422 naming
    ``body`` on every kind of route (a vehicle's lean route, FastAPI's, the login), its
    message saying why; never FastAPI's 400 "error parsing the body"."""
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    deep = b"[" * 10_000 + b"]" * 10_000
    bodies = [
        (b'{"instance_id": "' + iid.encode() + b'", "x": ' + deep + b"}", "nested too deep"),
        (b'{"instance_id": "' + iid.encode() + b'", "x": "\xff\xfe"}', "not valid UTF-8"),
        (b"\xff" * 8, "not valid UTF-8"),
        (b'{"instance_id": "' + iid.encode() + b'", "sam', "not valid JSON"),
        # JSON in UTF-16 or UTF-32 (Python's reader would take it, guessing)
        (json.dumps({"instance_id": iid}).encode("utf-16"), "not valid UTF-8"),
        (json.dumps({"instance_id": iid}).encode("utf-16-be"), "not valid UTF-8"),
        (json.dumps({"instance_id": iid}).encode("utf-32-le"), "not valid UTF-8"),
    ]
    routes = [("/upper/update_param", vh), ("/api/vehicles", ADMIN), ("/auth/token", {})]
    for path, who in routes:
        for body, why in bodies:
            headers = {**who, "content-type": "application/json"}
            r = await client.post(path, headers=headers, content=body)
            assert r.status_code == 422, (path, why, r.text)
            error = r.json()["error"]
            assert error["code"] == "invalid"
            assert [d["field"] for d in error["details"]] == ["body"], (path, why, error)
            assert why in error["details"][0]["message"], (path, why, error)
            assert why in error["message"], (path, why, error)


@pytest.mark.parametrize("seed", [1, 2])
async def test_garbage_at_every_route_never_500(client: httpx.AsyncClient, seed: int) -> None:
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    rng = random.Random(seed)
    paths = create_app(Settings()).openapi()["paths"]
    assert len(paths) > 15
    for template, operations in paths.items():
        path = (
            template.replace("{vehicle_id}", rng.choice([vid, "zz", "%00"]))
            .replace("{username}", rng.choice(["admin", "nobody"]))
            .replace("{command_id}", rng.choice(["c-1", "x" * 300]))
        )
        for method in (m.upper() for m in operations):
            for headers in (ADMIN, vh, {"Authorization": "Bearer \x7f"}, {}):
                for body in rng.sample(GARBAGE, 6):
                    params = {
                        "instance_id": rng.choice([iid, "", "nope"]),
                        "wait_s": rng.choice(["0", "-1", "abc", "99"]),
                        "max_points": rng.choice(["1", "0", "zz"]),
                        "from": rng.choice(["yesterday", "2026-11-22T00:00:00"]),
                        "after_seq": rng.choice(["-3", "x"]),
                        "format": rng.choice(["csv", "exe"]),
                    }
                    r = await client.request(
                        method, path, headers=headers, json=body, params=params
                    )
                    assert r.status_code < 500, (method, path, body, r.text)
                    if r.status_code >= 400:
                        assert "error" in r.json(), (method, path, r.text)


async def test_seq_starts_at_one(client: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    r = await client.post(
        "/upper/update_param",
        headers=vh,
        json={
            "instance_id": iid,
            "samples": [{"seq": 0, "ts": "2026-11-22T10:00:00Z", "lat": 1, "lon": 2}],
        },
    )
    assert r.status_code == 422
    assert r.json()["error"]["details"][0]["field"] == "samples.0.seq"


SAMPLE = {"seq": 1, "ts": "2026-11-22T10:00:00Z", "lat": 43.0, "lon": 15.0}


@pytest.mark.parametrize(
    ("route", "body", "field"),
    [
        ("/upper/update_param", {"samples": [{**SAMPLE, "lat": True}]}, "samples.0.lat"),
        ("/upper/update_param", {"samples": [{**SAMPLE, "lon": "15.5"}]}, "samples.0.lon"),
        ("/upper/update_param", {"samples": [{**SAMPLE, "seq": "30"}]}, "samples.0.seq"),
        ("/upper/update_param", {"samples": [{**SAMPLE, "seq": 3.0}]}, "samples.0.seq"),
        ("/upper/update_param", {"rtt_s": "0.1"}, "rtt_s"),
        ("/client/grant_control", {"user": "admin", "duration_s": True}, "duration_s"),
        ("/client/grant_control", {"user": "admin", "duration_s": "600"}, "duration_s"),
        ("/client/submit_control", {"command": {"type": "stop"}, "ttl_s": "60"}, "ttl_s"),
        (
            "/client/submit_control",
            {"command": {"type": "go_to", "args": {"lat": "43.9", "lon": 15.0}}},
            "command.args.lat",
        ),
        (
            "/client/submit_control",
            {"command": {"type": "follow_path", "args": {"waypoints": [], "plan": "yes"}}},
            "command.args.plan",
        ),
    ],
)
async def test_a_value_of_the_wrong_json_type_is_422_not_converted(
    client: httpx.AsyncClient, route: str, body: dict[str, object], field: str
) -> None:
    """A number is a JSON number and a flag a JSON boolean: ``true`` is not 1, ``"43"`` not
    43 (a sample at lat ``true`` was stored at 1.0)."""
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    headers = vh if route.startswith("/upper") else ADMIN
    extra = {"instance_ids": [iid]} if "submit" in route else {"instance_id": iid}
    r = await client.post(route, headers=headers, json={**extra, **body})
    assert r.status_code == 422, r.text
    assert field in [d["field"] for d in r.json()["error"]["details"]]


async def test_a_flag_of_the_wrong_json_type_is_422(client: httpx.AsyncClient) -> None:
    r = await client.patch("/api/users/admin", headers=ADMIN, json={"disabled": "yes"})
    assert r.status_code == 422, r.text
    assert r.json()["error"]["details"][0]["field"] == "disabled"


async def test_a_string_too_long_is_told_in_characters(client: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    ack = {"command_id": "c-1", "status": "accepted", "detail": "x" * 1000}
    r = await client.post(
        "/upper/update_fbmessage", headers=vh, json={"instance_id": iid, "acks": [ack]}
    )
    assert r.status_code == 422, r.text
    assert r.json()["error"]["details"] == [
        {"field": "acks.0.detail", "message": "String should have at most 512 characters"}
    ]
    r = await client.post(
        "/upper/start_instance", headers=vh, json={"vehicle_id": vid, "name": "n" * 200}
    )
    assert r.json()["error"]["details"][0]["message"].endswith("at most 128 characters")


async def test_a_message_never_sends_a_long_or_raw_id_back(client: httpx.AsyncClient) -> None:
    r = await client.get("/api/vehicles/" + "x" * 5000, headers=ADMIN)
    assert r.status_code == 422 and len(r.json()["error"]["message"]) <= 300
    r = await client.get("/api/vehicles/a%00b%1b%5B2J", headers=ADMIN)
    assert r.status_code == 404
    message = r.json()["error"]["message"]
    assert "\x00" not in message and "\x1b" not in message and "a\\x00b\\x1b[2J" in message


@pytest.mark.parametrize("content_type", ["application/x-www-form-urlencoded", "text/plain", None])
async def test_a_json_body_without_its_content_type_is_told_so(
    client: httpx.AsyncClient, content_type: str | None
) -> None:
    """``curl -d`` sends a form's content type: the answer says what is missing."""
    headers = {**ADMIN, **({"Content-Type": content_type} if content_type else {})}
    body = b'{"vehicle_id": "ct-1", "name": "x"}'
    r = await client.post("/api/vehicles", headers=headers, content=body)
    assert r.status_code == 422, r.text
    error = r.json()["error"]
    assert error["details"][0]["field"] == "body"
    assert "Content-Type: application/json" in error["message"]


async def test_an_unknown_event_kind_is_422_naming_the_kinds(client: httpx.AsyncClient) -> None:
    r = await client.get("/api/events", headers=ADMIN, params={"kind": "nonsense"})
    assert r.status_code == 422, r.text
    detail = r.json()["error"]["details"][0]
    assert detail["field"] == "kind" and "zone_breach" in detail["message"]
    r = await client.get("/api/events", headers=ADMIN, params={"kind": "presence"})
    assert r.status_code == 200


async def test_a_users_vehicles_are_kept_once_each(client: httpx.AsyncClient) -> None:
    a, _ = await make_vehicle(client)
    b, _ = await make_vehicle(client)
    body = {"username": "dup-1", "role": "operator", "vehicles": [a, b] * 1000}
    r = await client.post("/api/users", headers=ADMIN, json=body)
    assert r.status_code == 201, r.text
    assert sorted(r.json()["vehicles"]) == sorted([a, b])
    r = await client.patch("/api/users/dup-1", headers=ADMIN, json={"vehicles": [b, b]})
    assert r.status_code == 200 and r.json()["vehicles"] == [b]


async def test_a_login_sent_as_multipart_is_told_what_to_send(client: httpx.AsyncClient) -> None:
    r = await client.post("/auth/token", files={"username": (None, "a"), "password": (None, "b")})
    assert r.status_code == 422, r.text
    error = r.json()["error"]
    assert "x-www-form-urlencoded" in error["message"]
    assert error["details"] == [
        {"field": "body", "message": "multipart/form-data is not read here"}
    ]


@pytest.mark.parametrize(
    ("field", "bad", "good"),
    [
        ("depth_m", -1e308, -2.5),
        ("depth_m", 12_000.5, 10_935.0),
        ("speed_mps", 200.5, 0.0),
        ("heading_deg", 360.5, 360.0),
        ("battery_pct", -0.5, 100.0),
    ],
)
async def test_a_reading_past_any_real_one_is_422_naming_it(
    client: httpx.AsyncClient, field: str, bad: float, good: float
) -> None:
    """A sensor glitch (a depth of -1e308) never becomes the boat's position."""
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    sample = {"seq": 1, "ts": "2026-11-26T10:00:00Z", "lat": 43.9, "lon": 15.4}
    r = await client.post(
        "/upper/update_param",
        headers=vh,
        json={"instance_id": iid, "samples": [{**sample, field: bad}]},
    )
    assert r.status_code == 422, r.text
    assert [d["field"] for d in r.json()["error"]["details"]] == [f"samples.0.{field}"]
    r = await client.post(
        "/upper/update_param",
        headers=vh,
        json={"instance_id": iid, "samples": [{**sample, field: good}]},
    )
    assert r.status_code == 200 and r.json()["accepted"] == 1, r.text


async def test_an_id_too_long_to_be_one_is_422_naming_it(client: httpx.AsyncClient) -> None:
    """Every id is at most 64 characters: a longer one in a path was a 404 that wrote it
    back whole (5,000 characters); in an operator's heartbeat it was taken (200)."""
    long = "x" * 5000
    for path, field in (
        (f"/api/vehicles/{long}", "vehicle_id"),
        (f"/api/vehicles/{long}/failsafe", "vehicle_id"),
        (f"/api/zones/{long}", "zone_id"),
        (f"/api/users/{long}", "username"),
    ):
        r = await client.get(path, headers=ADMIN)
        assert r.status_code == 422, (path, r.status_code)
        assert [d["field"] for d in r.json()["error"]["details"]] == [field]
        assert long not in r.text
    r = await client.post("/client/heartbeat", headers=ADMIN, json={"instance_ids": [long]})
    assert r.status_code == 422 and r.json()["error"]["details"][0]["field"] == "instance_ids.0"
    assert (await client.get("/api/zones/z-0123", headers=ADMIN)).status_code == 404
