"""Gateway and vehicle tokens can be revoked and rotated by an admin (issue 12, finding 7):
the sockets holding the old token close with 4401, the old token gets 401 on HTTP, the
new one works. Real uvicorn, real websockets clients."""

from __future__ import annotations

import httpx
import pytest
import websockets

from tests.factories import ADMIN, bearer, make_user, make_vehicle
from tests.live import call, connect, recv_until

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")

CAPS = ["stop", "go_to"]


async def _close_code(ws: websockets.ClientConnection) -> int | None:
    with pytest.raises(websockets.ConnectionClosed):
        await recv_until(ws, lambda f: False, within_s=10)
    return ws.close_code


async def _gateway(api: httpx.AsyncClient, gateway_id: str) -> tuple[str, str]:
    vid, _ = await make_vehicle(api)
    r = await api.post(
        "/api/gateways", headers=ADMIN, json={"gateway_id": gateway_id, "vehicles": [vid]}
    )
    assert r.status_code == 201, r.text
    return vid, r.json()["token"]


async def _start_on_socket(ws: websockets.ClientConnection, vid: str) -> None:
    ack = await call(ws, "start_instance", "s1", vehicle_id=vid, capabilities=CAPS)
    assert ack["ok"] is True, ack


async def _start_http(api: httpx.AsyncClient, token: str, vid: str) -> int:
    r = await api.post("/upper/start_instance", headers=bearer(token), json={"vehicle_id": vid})
    return r.status_code


async def test_revoking_a_gateways_tokens_closes_its_socket(
    base: str, api: httpx.AsyncClient
) -> None:
    vid, token = await _gateway(api, "gw-revoke")
    async with await connect(base, "/ws/vehicle", token) as ws:
        await _start_on_socket(ws, vid)
        r = await api.post("/api/gateways/gw-revoke/revoke_tokens", headers=ADMIN)
        assert r.status_code == 200 and r.json() == {"ok": True}
        assert await _close_code(ws) == 4401
    assert await _start_http(api, token, vid) == 401
    async with await connect(base, "/ws/vehicle", token) as ws:
        assert await _close_code(ws) == 4401  # and no new socket either


async def test_rotating_a_gateways_token_closes_its_socket_and_the_new_one_works(
    base: str, api: httpx.AsyncClient
) -> None:
    vid, old = await _gateway(api, "gw-rotate")
    async with await connect(base, "/ws/vehicle", old) as ws:
        await _start_on_socket(ws, vid)
        r = await api.post("/api/gateways/gw-rotate/rotate_token", headers=ADMIN)
        assert r.status_code == 200, r.text
        body = r.json()
        assert body["gateway_id"] == "gw-rotate" and body["vehicles"] == [vid]
        new = body["token"]
        assert new.startswith("fct_") and new != old
        assert await _close_code(ws) == 4401
    assert await _start_http(api, old, vid) == 401
    assert await _start_http(api, new, vid) == 200
    async with await connect(base, "/ws/vehicle", new) as ws:
        await _start_on_socket(ws, vid)


async def test_revoking_a_vehicles_tokens_closes_its_socket(
    base: str, api: httpx.AsyncClient
) -> None:
    vid, headers = await make_vehicle(api)
    token = headers["Authorization"].removeprefix("Bearer ")
    async with await connect(base, "/ws/vehicle", token) as ws:
        await _start_on_socket(ws, vid)
        r = await api.post(f"/api/vehicles/{vid}/revoke_tokens", headers=ADMIN)
        assert r.status_code == 200 and r.json() == {"ok": True}
        assert await _close_code(ws) == 4401
    assert await _start_http(api, token, vid) == 401
    # A new token (rotate) brings the vehicle back.
    r = await api.post(f"/api/vehicles/{vid}/rotate_token", headers=ADMIN)
    assert await _start_http(api, r.json()["token"], vid) == 200


@pytest.mark.parametrize(
    "path",
    [
        "/api/gateways/gw-none/rotate_token",
        "/api/gateways/gw-none/revoke_tokens",
        "/api/vehicles/usv-none/revoke_tokens",
    ],
)
async def test_unknown_gateway_or_vehicle_is_404_and_non_admins_are_403(
    api: httpx.AsyncClient, path: str
) -> None:
    r = await api.post(path, headers=ADMIN)
    assert r.status_code == 404 and r.json()["error"]["code"] == "not_found"
    vid, token = await _gateway(api, "gw-kept")
    _, manager = await make_user(api, "manager", [vid])
    for route in (
        path,
        "/api/gateways/gw-kept/rotate_token",
        "/api/gateways/gw-kept/revoke_tokens",
        f"/api/vehicles/{vid}/revoke_tokens",
    ):
        r = await api.post(route, headers=manager)
        assert r.status_code == 403 and r.json()["error"]["code"] == "forbidden", route
        assert (await api.post(route, headers=bearer(token))).status_code == 403
    assert await _start_http(api, token, vid) == 200  # nothing was revoked


async def test_whoami_says_whom_a_vehicle_or_gateway_token_acts_for(
    base: str, api: httpx.AsyncClient
) -> None:
    """Over HTTP and as an op on the socket; a user's token is not a vehicle's."""
    vid, token = await _gateway(api, "gw-whoami")
    r = await api.get("/upper/whoami", headers=bearer(token))
    assert r.json() == {
        "kind": "gateway", "vehicle_id": None, "gateway_id": "gw-whoami", "vehicles": [vid]
    }  # fmt: skip
    other, vehicle_headers = await make_vehicle(api)
    r = await api.get("/upper/whoami", headers=vehicle_headers)
    assert (r.json()["kind"], r.json()["vehicle_id"], r.json()["vehicles"]) == (
        "vehicle", other, [other]
    )  # fmt: skip
    async with await connect(base, "/ws/vehicle", token) as ws:
        ack = await call(ws, "whoami", "w1")
        assert ack["ok"] is True and ack["gateway_id"] == "gw-whoami" and ack["vehicles"] == [vid]
    _, user_headers = await make_user(api, "operator", [vid])
    r = await api.get("/upper/whoami", headers=user_headers)
    assert r.status_code == 403 and r.json()["error"]["code"] == "forbidden"
    assert (await api.get("/upper/whoami")).status_code == 401
