"""``GET /api/me``: who a token acts for (the console asks it after logging in)."""

from __future__ import annotations

import httpx

from tests.factories import ADMIN, make_user, make_vehicle


async def test_a_session_says_its_user_role_vehicles_and_end(client: httpx.AsyncClient) -> None:
    v1, _ = await make_vehicle(client)
    v2, _ = await make_vehicle(client)
    name, _ = await make_user(client, "manager", [v2, v1], password="a harbour password")
    r = await client.post("/auth/token", json={"username": name, "password": "a harbour password"})
    session = {"Authorization": f"Bearer {r.json()['access_token']}"}
    me = (await client.get("/api/me", headers=session)).json()
    assert me["username"] == name and me["role"] == "manager"
    assert me["vehicles"] == sorted([v1, v2])
    assert me["expires_at"] is not None  # a session ends


async def test_an_api_token_runs_until_revoked(client: httpx.AsyncClient) -> None:
    me = (await client.get("/api/me", headers=ADMIN)).json()
    assert me["role"] == "admin" and me["expires_at"] is None


async def test_no_token_no_answer(client: httpx.AsyncClient) -> None:
    r = await client.get("/api/me")
    assert r.status_code == 401 and r.json()["error"]["code"] == "unauthorized"
