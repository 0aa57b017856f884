"""Requests refused as HTTP requests, before any field is read: a compressed body (415), a
query parameter given twice, an over-size body (413), a path or a method the API does not
have (404, 405 with every method of the path in ``Allow``, HEAD wherever GET)."""

from __future__ import annotations

import gzip
import json

import httpx
import pytest

from server.app import create_app
from server.settings import Settings
from tests.factories import ADMIN, make_vehicle, start_instance

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


async def test_a_compressed_body_is_415_naming_its_encoding(client: httpx.AsyncClient) -> None:
    """A gzip body (a client sending ``Content-Encoding: gzip``, which the server does not
    take) was read as UTF-16 (its first bytes ``1f 8b 08 00``), then said not to be UTF-8:
    the encoding is what is refused, and said."""
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    body = gzip.compress(json.dumps({"instance_id": iid}).encode(), mtime=0)
    headers = {**vh, "content-type": "application/json", "content-encoding": "gzip"}
    r = await client.post("/upper/heartbeat", headers=headers, content=body)
    assert r.status_code == 415, r.text
    error = r.json()["error"]
    assert error["code"] == "unsupported_media_type"
    assert [d["field"] for d in error["details"]] == ["Content-Encoding"]
    assert "Content-Encoding: gzip" in error["message"] and "uncompressed" in error["message"]
    plain = {**vh, "content-encoding": "identity"}  # no encoding at all: taken
    r = await client.post("/upper/heartbeat", headers=plain, json={"instance_id": iid})
    assert r.status_code == 200, r.text


async def test_a_query_parameter_given_twice_is_422_naming_it(client: httpx.AsyncClient) -> None:
    """No parameter of the API takes a list: a filter named twice would quietly keep one."""
    v1, vh = await make_vehicle(client)
    iid = (await start_instance(client, v1, vh))["instance_id"]
    for path, query in [
        ("/api/events", "vehicle_id=a&vehicle_id=b"),
        ("/client/get_param", f"instance_id={iid}&%69nstance_id={iid}"),  # %69 is "i"
        ("/upper/get_control", f"instance_id={iid}&wait_s=0&wait_s=1"),
    ]:
        who = vh if path.startswith("/upper") else ADMIN
        r = await client.get(f"{path}?{query}", headers=who)
        assert r.status_code == 422, (path, r.text)
        error = r.json()["error"]
        name = "wait_s" if "wait_s=1" in query else query.partition("=")[0]
        assert error["details"] == [
            {"field": name, "message": f"{name} is given more than once: give it once"}
        ]
    listed = await client.get(f"/client/get_param?instance_id={iid}&names=a&names=b", headers=ADMIN)
    assert listed.json()["error"]["message"] == (
        "names is given more than once: give it once, as a comma list (names=a,b)"
    )
    once = await client.get("/api/events", headers=ADMIN, params={"vehicle_id": v1, "limit": 5})
    assert once.status_code == 200, once.text


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
    # GET too, although the console's files answer GET for the paths no route has.
    for method, path in (("GET", "/upper/heartbeat"), ("GET", "/client/submit_control")):
        r = await client.request(method, path, headers=ADMIN)
        assert r.status_code == 405, (method, path, r.status_code)
        assert r.json()["error"]["code"] == "method_not_allowed" and "POST" in r.headers["allow"]
    assert (await client.head("/healthz")).status_code == 200  # HEAD wherever GET
    assert (await client.head("/upper/heartbeat")).status_code == 405
    assert (await client.get("/")).status_code == 200  # the console itself


@pytest.mark.parametrize("method", ["POST", "PUT", "PATCH", "DELETE", "GET"])
@pytest.mark.parametrize(
    "path", ["/api/nonexistent", "/upper/nope", "/client/nope", "/nope", "/api/vehicles/tv-1/nope"]
)
async def test_a_path_the_api_does_not_have_is_404_whatever_the_method(
    client: httpx.AsyncClient, method: str, path: str
) -> None:
    r = await client.request(method, path, headers=ADMIN)
    assert r.status_code == 404, (method, path, r.status_code, r.headers.get("allow"))
    assert r.json()["error"]["code"] == "not_found" and "allow" not in r.headers


@pytest.mark.parametrize(
    ("method", "path", "allow"),
    [
        ("PUT", "/api/zones", "GET, HEAD, POST"),
        ("DELETE", "/api/vehicles", "GET, HEAD, POST"),
        ("PUT", "/api/zones/z-1", "DELETE, GET, HEAD, PATCH"),
        ("GET", "/upper/heartbeat", "POST"),
        ("HEAD", "/upper/heartbeat", "POST"),
        ("POST", "/console/config.json", "GET, HEAD"),
    ],
)
async def test_a_405_allows_every_method_of_the_path(
    client: httpx.AsyncClient, method: str, path: str, allow: str
) -> None:
    """A path with a route per method: the Allow of a method it lacks lists them all
    (Starlette's named the first route's alone)."""
    r = await client.request(method, path, headers=ADMIN)
    assert r.status_code == 405, r.text
    assert r.headers["allow"] == allow
    if method == "HEAD":  # no body
        return
    error = r.json()["error"]
    assert error["code"] == "method_not_allowed" and allow in error["message"]
