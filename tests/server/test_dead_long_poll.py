"""A vehicle that dies in a long poll (its process killed, its connection closed) is not
kept online by the poll it left open, and nothing is handed to it."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from urllib.parse import urlsplit

import httpx
import pytest

from server.settings import Settings
from tests.factories import ADMIN, make_vehicle, start_instance
from tests.live import serve
from tests.server.commanding import eventually

pytestmark = pytest.mark.usefixtures("store_backend")


async def test_a_closed_long_poll_ends_contact_and_delivers_nothing(
    make_settings: Callable[..., Settings],
) -> None:
    settings = make_settings(stale_after_s=1, offline_after_s=2)
    async with serve(settings) as base, httpx.AsyncClient(base_url=base, timeout=10) as api:
        vid, vh = await make_vehicle(api)
        iid = (await start_instance(api, vid, vh))["instance_id"]
        at = urlsplit(base)
        _, writer = await asyncio.open_connection(at.hostname, at.port)
        writer.write(
            f"GET /upper/get_control?instance_id={iid}&wait_s=30 HTTP/1.1\r\n"
            f"Host: {at.netloc}\r\nAuthorization: {vh['Authorization']}\r\n\r\n".encode()
        )
        await writer.drain()

        async def presence() -> str:
            r = await api.get(f"/api/vehicles/{vid}", headers=ADMIN)
            return str(r.json()["presence"])

        async def polling_online() -> bool:  # the open poll is contact, past stale_after_s
            return await presence() == "online"

        await asyncio.sleep(1.5)  # past stale_after_s with only the poll open
        assert await polling_online()
        writer.close()  # the vehicle's process dies: its connection closes
        await writer.wait_closed()

        async def offline() -> bool:
            return await presence() == "offline"

        await eventually(offline, timeout_s=6.0)  # not at the poll's end, 30 s on
        stop = await api.post(
            "/client/submit_control",
            headers=ADMIN,
            json={"instance_ids": [iid], "command": {"type": "stop"}},
        )
        assert stop.status_code == 202, stop.text
        command_id = stop.json()["commands"][0]["command_id"]
        sent = (await api.get(f"/api/commands/{command_id}", headers=ADMIN)).json()
        assert sent["status"] == "queued", sent  # not "delivered" to nobody
        # The vehicle back: the stop is handed out at once (one delivered into the dead
        # poll would wait for its ack timeout first).
        back = await api.get("/upper/get_control", headers=vh, params={"instance_id": iid})
        assert [c["command_id"] for c in back.json()["commands"]] == [command_id]
