"""The vehicles' hot routes answer a plain request without FastAPI's request handler
(``server/api/lean.py``); every request gets the answer FastAPI's own handler gives.

Each case is sent twice to one app: as it is (the lean path, or FastAPI's when the
request is not plain), then with a dependency override set, which sends every request
through FastAPI's handler. The two answers must be the same.
"""

from __future__ import annotations

import json
from collections.abc import AsyncIterator, Callable
from typing import Any

import httpx
import pytest
from asgi_lifespan import LifespanManager
from fastapi import FastAPI
from fastapi.routing import APIRoute

from server.api.lean import LeanRoute, _LeanApp
from server.app import create_app
from server.settings import Settings
from tests.factories import ADMIN, bearer, make_vehicle, sample, start_instance, unique

HOT = {("POST", "/upper/update_param"), ("GET", "/upper/get_control")}


def _unused() -> None:  # the override that turns the lean path off
    return None


class Counted:
    """FastAPI's handler of a lean route, counting the requests it gets."""

    def __init__(self, standard: Any) -> None:
        self.standard = standard
        self.calls = 0

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        self.calls += 1
        await self.standard(scope, receive, send)


def standard_calls(app: FastAPI) -> int:
    return sum(
        r.app.standard.calls
        for r in app.router.routes
        if isinstance(r, LeanRoute) and isinstance(r.app, _LeanApp)
    )


@pytest.fixture
async def app(make_settings: Callable[..., Settings]) -> AsyncIterator[FastAPI]:
    app = create_app(make_settings())
    for route in app.router.routes:
        if isinstance(route, LeanRoute) and isinstance(route.app, _LeanApp):
            route.app.standard = Counted(route.app.standard)
    async with LifespanManager(app):
        yield app


@pytest.fixture
async def client(app: FastAPI) -> AsyncIterator[httpx.AsyncClient]:
    transport = httpx.ASGITransport(app=app)
    async with httpx.AsyncClient(transport=transport, base_url="http://test") as c:
        yield c


async def both(
    app: FastAPI, client: httpx.AsyncClient, method: str, url: str, **kwargs: Any
) -> tuple[httpx.Response, httpx.Response]:
    lean = await client.request(method, url, **kwargs)
    app.dependency_overrides[_unused] = _unused
    try:
        before = standard_calls(app)
        standard = await client.request(method, url, **kwargs)
        assert standard_calls(app) == before + 1  # the override: FastAPI's handler
    finally:
        app.dependency_overrides.clear()
    return lean, standard


async def test_a_plain_request_skips_fastapis_handler(
    app: FastAPI, client: httpx.AsyncClient
) -> None:
    _, iid, vh = await _instance(client)
    before = standard_calls(app)
    r = await client.post(
        "/upper/update_param", headers=vh, json={"instance_id": iid, "samples": [sample(1)]}
    )
    assert r.status_code == 200 and r.json()["accepted"] == 1, r.text
    r = await client.get(f"/upper/get_control?instance_id={iid}&wait_s=0", headers=vh)
    assert r.status_code == 200 and r.json()["commands"] == [], r.text
    r = await client.get(f"/upper/get_control?instance_id={iid}", headers={})
    assert r.status_code == 401, r.text  # valid input, no token: the same dependency says no
    assert standard_calls(app) == before
    r = await client.post("/upper/update_param", headers=vh, content=b"{not json")
    assert r.status_code == 422, r.text
    assert standard_calls(app) == before + 1


def same(lean: httpx.Response, standard: httpx.Response) -> None:
    assert lean.status_code == standard.status_code, (lean.text, standard.text)
    assert lean.headers.get("content-type") == standard.headers.get("content-type")
    assert lean.headers.get("retry-after") == standard.headers.get("retry-after")
    assert lean.content == standard.content


def test_the_hot_routes_are_served_lean_and_the_others_by_fastapi() -> None:
    app = create_app(Settings(_env_file=None))
    routes = {
        (method, r.path): r
        for r in app.router.routes
        if isinstance(r, APIRoute)
        for method in r.methods
    }
    for key in HOT:
        assert isinstance(routes[key], LeanRoute) and isinstance(routes[key].app, _LeanApp), key
    # start_instance answers a model (FastAPI writes it): FastAPI's handler serves it.
    assert not isinstance(routes[("POST", "/upper/start_instance")].app, _LeanApp)


async def _instance(client: httpx.AsyncClient) -> tuple[str, str, dict[str, str]]:
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    return vid, iid, vh


async def test_update_param_answers_as_fastapi_does(
    app: FastAPI, client: httpx.AsyncClient
) -> None:
    vid, iid, vh = await _instance(client)
    _, other_iid, other = await _instance(client)
    json_type = {"content-type": "application/json"}

    def body(**fields: Any) -> str:
        return json.dumps({"instance_id": iid, **fields})

    cases: list[tuple[dict[str, str], str | bytes]] = [
        (json_type, body(samples=[sample(1)], params={"mode": "auto"})),  # plain: both 200
        (json_type, body(samples=[sample(1)], unknown=1)),  # now duplicates, both
        ({"content-type": "application/json; charset=utf-8"}, body()),
        ({"content-type": "application/vnd.fleet+json"}, body()),
        ({}, body()),  # no content type
        ({"content-type": "text/plain"}, body()),
        (json_type, b""),
        (json_type, b"null"),
        (json_type, b"[]"),
        (json_type, b"{not json"),
        (json_type, body(samples=[{**sample(2), "lat": 91}])),
        (json_type, body(samples=[sample(3, data="@")]).replace('"@"', '{"x": NaN}')),
        (json_type, body(samples=[sample(3, data="@")]).replace('"@"', '{"x": "a\\ud800"}')),
        (json_type, json.dumps({"samples": []})),  # no instance_id
        (json_type, body(samples=[sample(4)] * 2)),
        (json_type, json.dumps({"instance_id": other_iid})),  # another vehicle's: 404
        (json_type, "\ufeff" + body()),
    ]
    for extra, content in cases:
        for auth in (vh, {}, {"Authorization": "Bearer fct_nope"}, ADMIN, other):
            lean, standard = await both(
                app,
                client,
                "POST",
                "/upper/update_param",
                headers={**auth, **extra},
                content=content,
            )
            if lean.status_code == 200:
                assert standard.status_code == 200, standard.text
                assert lean.json().keys() == standard.json().keys()
            else:
                same(lean, standard)

    # A gateway acts for the vehicles it lists.
    r = await client.post(
        "/api/gateways", headers=ADMIN, json={"gateway_id": unique("gw"), "vehicles": [vid]}
    )
    assert r.status_code == 201, r.text
    gh = bearer(r.json()["token"])
    lean, standard = await both(
        app, client, "POST", "/upper/update_param", headers=gh, json={"instance_id": iid}
    )
    assert lean.status_code == standard.status_code == 200
    # A finished instance takes no more calls.
    r = await client.post("/upper/finish_instance", headers=vh, json={"instance_id": iid})
    assert r.status_code == 200, r.text
    same(*await both(app, client, "POST", "/upper/update_param", headers=vh, content=body()))


async def test_get_control_answers_as_fastapi_does(app: FastAPI, client: httpx.AsyncClient) -> None:
    _, iid, vh = await _instance(client)
    _, other_iid, other = await _instance(client)
    queries = [
        f"instance_id={iid}",
        f"instance_id={iid}&wait_s=0",
        f"instance_id={iid}&wait_s=0.0",
        f"wait_s=0&instance_id={iid}",
        # (a name given twice is refused before any route: test_bad_input)
        "",
        "instance_id=",
        "instance_id=" + "x" * 65,
        f"instance_id={iid}&wait_s=",
        f"instance_id={iid}&wait_s=-1",
        f"instance_id={iid}&wait_s=31",
        f"instance_id={iid}&wait_s=nan",
        f"instance_id={iid}&wait_s=inf",
        f"instance_id={iid}&wait_s=abc",
        f"instance_id={other_iid}",
        "instance_id=i-unknown",
        # read by the lean path itself, or left to Starlette when there is something to decode
        f"&instance_id={iid}&&wait_s=0&",
        f"instance_id={iid}&wait_s",
        f"instance_id={iid}&other=a=b",
        f"instance_id={iid}&wait_s=0%2E5",
        f"instance_id={iid}&wait_s=+0",
        f"instance_id=%69{iid[1:]}",
        f"instance_id={iid}&note=%C3%A9",
    ]
    for query in queries:
        for auth in (vh, {}, {"Authorization": "Bearer fct_nope"}, ADMIN, other):
            lean, standard = await both(
                app, client, "GET", f"/upper/get_control?{query}", headers=auth
            )
            same(lean, standard)
