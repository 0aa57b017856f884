"""Every read path serves what is stored (issue 12, finding 11): data an older version
stored nested far deeper than today's limit, in an event and in a vehicle's latest
position, is served over HTTP and in the sockets' snapshots, never a 500 or a 1011."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import httpx
import pytest

from fleet_protocol import MAX_JSON_DEPTH, parse_ts
from server.app import create_app
from server.settings import Settings
from tests.factories import ADMIN, ADMIN_TOKEN, make_vehicle, sample, start_instance
from tests.live import call, connect, recv_until, serve

pytestmark = pytest.mark.usefixtures("store_backend")

DEPTH = 90  # BSON holds it (MongoDB stops at 100); the wire models refuse past 32


def deep(levels: int) -> Any:
    value: Any = "bottom"
    for _ in range(levels):
        value = {"d": value}
    return value


async def test_deeply_nested_stored_data_is_served_everywhere(
    make_settings: Callable[..., Settings],
) -> None:
    assert DEPTH > MAX_JSON_DEPTH
    app = create_app(make_settings())
    async with serve(Settings(), app=app) as base, httpx.AsyncClient(base_url=base) as api:
        vid, vh = await make_vehicle(api)
        iid = (await start_instance(api, vid, vh))["instance_id"]
        r = await api.post(
            "/upper/update_param", headers=vh, json={"instance_id": iid, "samples": [sample(1)]}
        )
        assert r.status_code == 200, r.text
        # What an older version let through, written as it would have been.
        services = app.state.services
        await services.events.record("note", vehicle_id=vid, data={"deep": deep(DEPTH)})
        stored = {**sample(2), "data": deep(DEPTH)}
        services.instances.current_by_id(iid).position = {**stored, "ts": parse_ts(stored["ts"])}

        r = await api.get("/api/events", headers=ADMIN, params={"vehicle_id": vid})
        assert r.status_code == 200, r.text
        assert any(e["kind"] == "note" for e in r.json()["events"])
        r = await api.get("/api/vehicles", headers=ADMIN)
        assert r.status_code == 200, r.text
        async with await connect(base, "/ws/client", ADMIN_TOKEN) as ws:
            topics = ["fleet", f"vehicle/{vid}/events", f"vehicle/{vid}/telemetry"]
            assert (await call(ws, "subscribe", "s", topics=topics))["ok"] is True
            seen = set()
            while seen != set(topics):
                event = await recv_until(ws, lambda f: f["op"] == "event" and f.get("snapshot"))
                seen.add(event["topic"])
            assert (await call(ws, "subscribe", "again", topics=["fleet"]))["ok"] is True
