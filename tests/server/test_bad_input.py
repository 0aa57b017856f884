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


async def test_over_size_body_is_413(make_settings: object) -> None:
    from asgi_lifespan import LifespanManager

    settings: Settings = make_settings(max_body_bytes=2048)  # type: ignore[operator]
    app = create_app(settings)
    async with LifespanManager(app) as m:
        async with httpx.AsyncClient(
            transport=httpx.ASGITransport(app=m.app), base_url="http://t"
        ) as c:
            r = await c.post(
                "/api/vehicles", headers=ADMIN, content=json.dumps({"name": "x" * 5000}).encode()
            )
            assert r.status_code == 413
            assert r.json()["error"]["code"] == "too_large"


async def test_unknown_route_and_method_are_enveloped(client: httpx.AsyncClient) -> None:
    r = await client.get("/api/nothing-here", headers=ADMIN)
    assert r.status_code == 404 and r.json()["error"]["code"] == "not_found"
    r = await client.delete("/upper/start_instance", headers=ADMIN)
    assert r.status_code == 405 and "error" in r.json()


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
