"""A token's life on the sockets and long polls: authenticated by a first frame instead of
the URL; revoked or expired, it ends at once every long poll and socket that holds it."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import AsyncIterator, Callable

import httpx
import pytest
import websockets

from server.settings import Settings
from tests.factories import ADMIN, ADMIN_TOKEN, make_user, make_vehicle, start_instance
from tests.live import recv_json, recv_until, serve, ws_url

pytestmark = pytest.mark.usefixtures("store_backend")


@pytest.fixture
async def base(make_settings: Callable[..., Settings]) -> AsyncIterator[str]:
    async with serve(make_settings(ws_auth_wait_s=0.5)) as url:
        yield url


async def closed_with(ws: websockets.ClientConnection, within_s: float = 10) -> int | None:
    with pytest.raises(websockets.ConnectionClosed):
        await recv_until(ws, lambda f: False, within_s=within_s)
    return ws.close_code


async def test_a_socket_authenticates_with_its_first_frame(base: str) -> None:
    async with websockets.connect(ws_url(base, "/ws/client")) as ws:
        await ws.send(json.dumps({"op": "auth", "id": "a", "token": ADMIN_TOKEN}))
        ack = await recv_json(ws)
        assert (ack["op"], ack["id"], ack["ok"], ack["kind"]) == ("ack", "a", True, "user")
        await ws.send(json.dumps({"op": "subscribe", "id": "s", "topics": ["fleet"]}))
        assert (await recv_until(ws, lambda f: f.get("id") == "s"))["ok"] is True
    async with websockets.connect(ws_url(base, "/ws/client")) as ws:
        await ws.send(json.dumps({"op": "auth", "token": "fct_not-a-token"}))
        assert await closed_with(ws) == 4401
    async with websockets.connect(ws_url(base, "/ws/client")) as ws:  # says nothing
        assert await closed_with(ws, within_s=5) == 4401


async def test_a_revoked_token_ends_an_open_long_poll_at_once(base: str) -> None:
    async with httpx.AsyncClient(base_url=base, timeout=20) as api:
        vid, vh = await make_vehicle(api)
        iid = (await start_instance(api, vid, vh))["instance_id"]
        poll = asyncio.ensure_future(
            api.get("/upper/get_control", headers=vh, params={"instance_id": iid, "wait_s": 15})
        )
        await asyncio.sleep(0.3)  # the poll is open (a deadline below checks it ended early)
        assert not poll.done()
        r = await api.post(f"/api/vehicles/{vid}/rotate_token", headers=ADMIN)
        assert r.status_code == 200, r.text
        revoked_at = time.monotonic()
        # A command submitted now must not reach the old token's poll.
        await api.post(
            "/client/submit_control",
            headers=ADMIN,
            json={"instance_ids": [iid], "command": {"type": "stop"}},
        )
        answer = await asyncio.wait_for(poll, 5)
        assert answer.status_code == 401, answer.text
        assert time.monotonic() - revoked_at < 1.0
        fresh = {"Authorization": f"Bearer {r.json()['token']}"}
        r = await api.get("/upper/get_control", headers=fresh, params={"instance_id": iid})
        assert [c["type"] for c in r.json()["commands"]] == ["stop"]  # still there, for the new


async def test_a_session_socket_closes_when_its_token_expires(
    make_settings: Callable[..., Settings],
) -> None:
    settings = make_settings()
    settings.token_ttl_s = 1  # a session of one second (the setting's floor is 60)
    async with serve(settings) as base, httpx.AsyncClient(base_url=base, timeout=10) as api:
        await make_user(api, "viewer", [], username="sam", password="a long passphrase")
        r = await api.post("/auth/token", json={"username": "sam", "password": "a long passphrase"})
        assert r.status_code == 200, r.text
        session = r.json()["access_token"]
        async with websockets.connect(ws_url(base, "/ws/client")) as ws:
            await ws.send(json.dumps({"op": "auth", "id": "a", "token": session}))
            assert (await recv_json(ws))["ok"] is True
            opened = time.monotonic()
            assert await closed_with(ws, within_s=10) == 4401  # idle: no frame needed
            assert 0.5 < time.monotonic() - opened < 5
        r = await api.get("/api/vehicles", headers={"Authorization": f"Bearer {session}"})
        assert r.status_code == 401


async def test_logging_out_ends_a_session_token_and_its_socket_but_no_api_token(
    base: str,
) -> None:
    async with httpx.AsyncClient(base_url=base, timeout=10) as api:
        _, api_headers = await make_user(
            api, "operator", [], username="lea", password="a long passphrase"
        )
        r = await api.post("/auth/token", json={"username": "lea", "password": "a long passphrase"})
        session = {"Authorization": f"Bearer {r.json()['access_token']}"}
        async with websockets.connect(ws_url(base, "/ws/client", r.json()["access_token"])) as ws:
            await ws.send(json.dumps({"op": "subscribe", "id": "s", "topics": ["fleet"]}))
            assert (await recv_until(ws, lambda f: f.get("id") == "s"))["ok"] is True
            out = await api.post("/auth/logout", headers=session)
            assert (out.status_code, out.json()) == (200, {"ended": True})
            assert await closed_with(ws) == 4401
        assert (await api.get("/api/me", headers=session)).status_code == 401
        # an API token (an admin's first, a script's) is not ended by a console's logout
        kept = await api.post("/auth/logout", headers=api_headers)
        assert (kept.status_code, kept.json()) == (200, {"ended": False})
        assert (await api.get("/api/me", headers=api_headers)).status_code == 200
