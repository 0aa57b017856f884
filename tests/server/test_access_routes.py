"""Who may call what over HTTP: every route of the OpenAPI document, against every kind of
caller (``access_world.py``), with the outcome expected in each cell.

The rows are checked against the app's own OpenAPI document: a route added later without
a row here fails this test. Each cell runs in a world of its own (fresh ids), so that one
caller's success does not change the next one's answer.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from typing import Any

import httpx
import pytest
from asgi_lifespan import LifespanManager

from server.app import create_app
from server.settings import Settings
from tests.factories import sample
from tests.server.access_world import CALLERS, World, build

Call = Callable[[World], tuple[str, dict[str, Any]]]


def get(path: str, **params: Any) -> Callable[[World], tuple[str, dict[str, Any]]]:
    return lambda w: (path.format(w=w), {"params": {k: v.format(w=w) for k, v in params.items()}})


def post(path: str, body: Callable[[World], Any] | None = None) -> Call:
    return lambda w: (path.format(w=w), {"json": body(w) if body else {}})


USERS = {"viewer": 200, "operator": 200, "manager": 200, "admin": 200}
KINDS = {"vehicle": 403, "foreign": 403, "gateway": 403}
DEAD = {"anon": 401, "revoked": 401, "expired": 401}


def everyone(status: int) -> dict[str, int]:
    return dict.fromkeys(CALLERS, status)


def users(**cells: int) -> dict[str, int]:
    """A route for users: the vehicles' tokens are refused, the dead ones are 401."""
    return {**DEAD, **KINDS, **USERS, **cells}


def admin(status: int = 200) -> dict[str, int]:
    return users(viewer=403, operator=403, manager=403, admin=status)


def upper(**cells: int) -> dict[str, int]:
    """A route for vehicles and gateways: the users' tokens are refused."""
    return {**DEAD, **dict.fromkeys(USERS, 403), "vehicle": 200, "gateway": 200, **cells}


def go_to(w: World) -> dict[str, Any]:
    return {"instance_ids": [w.iid], "command": {"type": "go_to", "args": {"lat": 1, "lon": 2}}}


def patch(path: str, body: dict[str, Any]) -> Call:
    return lambda w: (path.format(w=w), {"json": body, "method": "PATCH"})


def put(path: str, body: dict[str, Any]) -> Call:
    return lambda w: (path.format(w=w), {"json": body, "method": "PUT"})


def delete(path: str) -> Call:
    return lambda w: (path.format(w=w), {"method": "DELETE"})


#: (method, path) -> (how to call it in a world, the outcome per caller).
ROWS: dict[tuple[str, str], tuple[Call, dict[str, int]]] = {
    ("GET", "/healthz"): (get("/healthz"), everyone(200)),
    ("GET", "/readyz"): (get("/readyz"), everyone(200)),
    ("GET", "/metrics"): (get("/metrics"), everyone(200)),
    ("POST", "/auth/token"): (
        post(
            "/auth/token",
            lambda w: {"username": w.password_user, "password": "correct horse battery"},
        ),
        everyone(200),  # the password decides, not the bearer
    ),
    ("GET", "/api/me"): (get("/api/me"), users()),
    ("POST", "/auth/logout"): (post("/auth/logout"), users()),  # ends session tokens alone
    ("GET", "/api/vehicles"): (get("/api/vehicles"), users()),
    ("POST", "/api/vehicles"): (
        post("/api/vehicles", lambda w: {"vehicle_id": f"new-{w.n}"}),
        admin(201),
    ),
    ("GET", "/api/vehicles/{vehicle_id}"): (get("/api/vehicles/{w.vid}"), users()),
    ("PATCH", "/api/vehicles/{vehicle_id}"): (
        patch("/api/vehicles/{w.vid}", {"vehicle_type": "usv"}),  # as it is: nothing moves
        admin(),
    ),
    ("POST", "/api/vehicles/{vehicle_id}/rotate_token"): (
        post("/api/vehicles/{w.vid}/rotate_token"),
        admin(),
    ),
    ("POST", "/api/vehicles/{vehicle_id}/revoke_tokens"): (
        post("/api/vehicles/{w.vid}/revoke_tokens"),
        admin(),
    ),
    ("GET", "/api/vehicles/{vehicle_id}/telemetry"): (
        get("/api/vehicles/{w.vid}/telemetry"),
        users(),
    ),
    ("GET", "/api/vehicles/{vehicle_id}/track"): (get("/api/vehicles/{w.vid}/track"), users()),
    ("GET", "/api/commands/{command_id}"): (get("/api/commands/{w.command_id}"), users()),
    ("GET", "/api/events"): (get("/api/events"), users()),
    ("GET", "/api/dead_letters"): (get("/api/dead_letters"), admin()),
    ("GET", "/api/gateways"): (get("/api/gateways"), admin()),
    ("POST", "/api/gateways"): (
        post("/api/gateways", lambda w: {"gateway_id": f"gnew-{w.n}", "vehicles": [w.vid]}),
        admin(201),
    ),
    ("POST", "/api/gateways/{gateway_id}/rotate_token"): (
        post("/api/gateways/{w.gateway_id}/rotate_token"),
        admin(),
    ),
    ("POST", "/api/gateways/{gateway_id}/revoke_tokens"): (
        post("/api/gateways/{w.gateway_id}/revoke_tokens"),
        admin(),
    ),
    ("GET", "/api/obstacles"): (get("/api/obstacles"), users()),
    ("POST", "/api/obstacles"): (
        post(
            "/api/obstacles",
            lambda w: {
                "name": "buoy",
                "polygon": {
                    "type": "Polygon",
                    "coordinates": [[[5, 5], [5, 6], [6, 6], [6, 5], [5, 5]]],
                },
            },
        ),
        admin(201),
    ),
    ("DELETE", "/api/obstacles/{obstacle_id}"): (
        delete("/api/obstacles/{w.obstacle_id}"),
        admin(),
    ),
    ("GET", "/api/vehicles/{vehicle_id}/failsafe"): (
        get("/api/vehicles/{w.vid}/failsafe"),
        users(),
    ),
    ("PUT", "/api/vehicles/{vehicle_id}/failsafe"): (
        put("/api/vehicles/{w.vid}/failsafe", {"action": "stop", "after_s": 10}),
        users(viewer=403, operator=403),  # the vehicle's field manager, an admin
    ),
    ("GET", "/api/vehicles/{vehicle_id}/audit"): (get("/api/vehicles/{w.vid}/audit"), users()),
    ("GET", "/api/zones"): (get("/api/zones"), users()),
    ("GET", "/api/zones/changes"): (
        get("/api/zones/changes", **{"from": "2026-01-01T00:00:00Z", "to": "2099-01-01T00:00:00Z"}),
        users(),
    ),
    ("GET", "/api/zones/{zone_id}"): (get("/api/zones/{w.zone_id}"), users()),
    ("POST", "/api/zones"): (
        post(
            "/api/zones",
            lambda w: {
                "name": "shoal",
                "kind": "no_go",
                "polygon": {
                    "type": "Polygon",
                    "coordinates": [[[20, 20], [20, 21], [21, 21], [21, 20], [20, 20]]],
                },
            },
        ),
        admin(201),
    ),
    ("PATCH", "/api/zones/{zone_id}"): (patch("/api/zones/{w.zone_id}", {"name": "x"}), admin()),
    ("DELETE", "/api/zones/{zone_id}"): (delete("/api/zones/{w.zone_id}"), admin()),
    ("GET", "/api/users"): (get("/api/users"), admin()),
    ("POST", "/api/users"): (
        post("/api/users", lambda w: {"username": f"new-{w.n}", "role": "viewer"}),
        admin(201),
    ),
    ("GET", "/api/users/{username}"): (get("/api/users/viewer-{w.n}"), admin()),
    ("PATCH", "/api/users/{username}"): (
        patch("/api/users/viewer-{w.n}", {"vehicles": []}),
        admin(),
    ),
    ("POST", "/api/users/{username}/revoke_tokens"): (
        post("/api/users/viewer-{w.n}/revoke_tokens"),
        admin(),
    ),
    ("POST", "/api/users/{username}/rotate_token"): (
        post("/api/users/viewer-{w.n}/rotate_token"),
        admin(),
    ),
    ("POST", "/client/connect_instance"): (
        post("/client/connect_instance", lambda w: {"instance_id": w.iid}),
        users(),
    ),
    ("GET", "/client/get_param"): (get("/client/get_param", instance_id="{w.iid}"), users()),
    ("GET", "/client/get_fbmessage"): (
        get("/client/get_fbmessage", instance_id="{w.iid}"),
        users(),
    ),
    ("POST", "/client/submit_control"): (
        post("/client/submit_control", go_to),
        users(viewer=403, operator=202, manager=409, admin=409),  # the operator holds it
    ),
    ("POST", "/client/cancel_command"): (
        post("/client/cancel_command", lambda w: {"command_id": w.command_id}),
        users(viewer=403),  # its issuer (the holder), the manager, an admin
    ),
    ("POST", "/client/request_control"): (
        post("/client/request_control", lambda w: {"instance_id": w.iid}),
        users(viewer=403, operator=409),  # the operator holds it: nothing to ask
    ),
    ("GET", "/client/control_requests"): (get("/client/control_requests"), users()),
    ("POST", "/client/grant_control"): (
        post(
            "/client/grant_control",
            lambda w: {"instance_id": w.iid, "user": f"operator-{w.n}", "duration_s": 60},
        ),
        users(viewer=403, operator=403),
    ),
    ("POST", "/client/deny_control"): (
        post("/client/deny_control", lambda w: {"instance_id": w.iid, "user": "nobody-asked"}),
        users(viewer=403, operator=403, manager=404, admin=404),  # no such request pending
    ),
    ("POST", "/client/revoke_control"): (
        post("/client/revoke_control", lambda w: {"instance_id": w.iid}),
        users(viewer=403, operator=403),
    ),
    ("POST", "/client/release_control"): (
        post("/client/release_control", lambda w: {"instance_id": w.iid}),
        users(viewer=403, manager=409, admin=409),  # only the holder releases
    ),
    ("POST", "/client/heartbeat"): (
        post("/client/heartbeat", lambda w: {"instance_ids": [w.iid]}),
        users(viewer=403),  # an operator or above: held lists where it holds the lease
    ),
    ("POST", "/upper/start_instance"): (
        post("/upper/start_instance", lambda w: {"vehicle_id": w.vid}),
        upper(foreign=403),  # it does not act for that vehicle
    ),
    ("POST", "/upper/finish_instance"): (
        post("/upper/finish_instance", lambda w: {"instance_id": w.iid}),
        upper(foreign=404),  # another vehicle's instance is not the foreign one's to see
    ),
    ("GET", "/upper/whoami"): (get("/upper/whoami"), upper(foreign=200)),  # whom it acts for
    ("POST", "/upper/heartbeat"): (
        post("/upper/heartbeat", lambda w: {"instance_id": w.iid}),
        upper(foreign=404),
    ),
    ("POST", "/upper/update_param"): (
        post(
            "/upper/update_param",
            lambda w: {"instance_id": w.iid, "samples": [sample(1)], "params": {"mode": "x"}},
        ),
        upper(foreign=404),
    ),
    ("POST", "/upper/update_fbmessage"): (
        post(
            "/upper/update_fbmessage",
            lambda w: {
                "instance_id": w.iid,
                "acks": [{"command_id": w.command_id, "status": "accepted"}],
            },
        ),
        upper(foreign=404),
    ),
    ("GET", "/upper/get_control"): (
        get("/upper/get_control", instance_id="{w.iid}"),
        upper(foreign=404),
    ),
}


@pytest.fixture
async def app_client(make_settings: Callable[..., Settings]) -> AsyncIterator[tuple[Any, Any]]:
    app = create_app(make_settings())
    async with LifespanManager(app) as m:
        transport = httpx.ASGITransport(app=m.app)
        async with httpx.AsyncClient(transport=transport, base_url="http://t") as c:
            yield app, c


def test_every_route_of_the_document_has_a_row() -> None:
    document = create_app(Settings(_env_file=None)).openapi()
    routes = {
        (method.upper(), path)
        for path, item in document["paths"].items()
        for method in item
        if method in ("get", "post", "put", "patch", "delete")
    }
    assert routes - set(ROWS) == set(), "a route without a row: say who may call it"
    assert set(ROWS) - routes == set(), "a row for a route that is gone"


@pytest.mark.parametrize(("method", "path"), sorted(ROWS))
async def test_each_caller_gets_what_its_cell_says(
    app_client: tuple[Any, httpx.AsyncClient], method: str, path: str
) -> None:
    app, c = app_client
    call, expected = ROWS[(method, path)]
    assert set(expected) == set(CALLERS), f"{method} {path}: a cell is missing"
    got = {}
    for caller in CALLERS:
        world = await build(c, app)
        url, kwargs = call(world)
        verb = kwargs.pop("method", method)
        r = await c.request(verb, url, headers=world.headers(caller), **kwargs)
        got[caller] = r.status_code
        if r.status_code >= 400 and path not in ("/metrics",):
            assert set(r.json()["error"]) == {"code", "message", "details"}, r.text
    assert got == expected
