"""A user's sockets when an admin changes the user: a change of role or vehicles closes
them with 4012 (connect again: the token still stands, the subscriptions were checked
against the former rights), a change of nothing leaves them open, and disabling the user
closes them with 4401 (its API token and its sessions alike), as its reconnection is."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import httpx
import pytest
import websockets

from fleet_protocol.links import CLOSE_RECONNECT
from server.settings import Settings
from tests.factories import ADMIN, make_user, make_vehicle, start_instance
from tests.fleetctl_run import token_of
from tests.live import call, connect, recv_until, serve

pytestmark = pytest.mark.usefixtures("store_backend")


async def _closed_with(ws: Any) -> int | None:
    with pytest.raises(websockets.ConnectionClosed):
        await recv_until(ws, lambda f: False, within_s=10)
    return int(ws.close_code) if ws.close_code is not None else None


def _fleet_ids(frame: dict[str, Any]) -> set[str]:
    return {v["vehicle_id"] for v in frame["data"]["vehicles"]}


async def test_new_rights_close_the_user_s_sockets_to_reconnect_with(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        one, oh = await make_vehicle(c)
        two, th = await make_vehicle(c)
        for vid, vh in ((one, oh), (two, th)):
            await start_instance(c, vid, vh)
        name, headers = await make_user(c, "operator", [one])
        token = token_of(headers)

        async with await connect(base, "/ws/client", token) as ws:
            assert (await call(ws, "subscribe", "s", topics=["fleet"]))["ok"]
            snapshot = await recv_until(ws, lambda f: f.get("topic") == "fleet")
            assert _fleet_ids(snapshot) == {one}
            as_they_are: list[dict[str, Any]] = [
                {},
                {"role": "operator"},
                {"vehicles": [one, one]},
                {"disabled": False},
                {"role": "operator", "vehicles": [one], "disabled": False},
            ]
            for n, body in enumerate(as_they_are):  # nothing changed: nothing to reconnect for
                same = await c.patch(f"/api/users/{name}", headers=ADMIN, json=body)
                assert same.status_code == 200, same.text
                assert (await call(ws, "subscribe", f"again-{n}", topics=["fleet"]))["ok"], body
            more = await c.patch(f"/api/users/{name}", headers=ADMIN, json={"vehicles": [one, two]})
            assert more.status_code == 200, more.text
            assert await _closed_with(ws) == CLOSE_RECONNECT
            assert "rights changed" in str(ws.close_reason)

        async with await connect(base, "/ws/client", token) as ws:  # the same token
            assert (await call(ws, "subscribe", "s", topics=["fleet"]))["ok"]
            snapshot = await recv_until(ws, lambda f: f.get("topic") == "fleet")
            assert _fleet_ids(snapshot) == {one, two}
            off = await c.patch(f"/api/users/{name}", headers=ADMIN, json={"disabled": True})
            assert off.status_code == 200, off.text
            assert await _closed_with(ws) == 4401  # as a revoked token: not to reconnect
            assert "its user disabled" in str(ws.close_reason)

        async with await connect(base, "/ws/client", token) as ws:
            assert await _closed_with(ws) == 4401  # disabled: the token no longer stands
