"""/ws/client: what the server's topics tell a console beside the vehicles' data: that the
zones changed, and each vehicle's recent events (snapshot) without gaps."""

from __future__ import annotations

import httpx
import pytest

from tests.factories import ADMIN, make_user
from tests.live import call, connect, recv_until
from tests.server.test_ws_client import _vehicle_with_instance, tok

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


async def test_zones_says_to_users_that_the_zones_changed(
    base: str, api: httpx.AsyncClient
) -> None:
    """The ``zones`` topic (an extension): a zone drawn for every vehicle is recorded for
    none, so no vehicle's events say it; users hear it here and read their zones again."""
    vid, vh, _ = await _vehicle_with_instance(api)
    _, viewer = await make_user(api, "viewer", [vid])
    ring = [[15.0, 43.0], [15.01, 43.0], [15.01, 43.01], [15.0, 43.0]]
    zone = {"name": "reef", "kind": "no_go", "polygon": {"type": "Polygon", "coordinates": [ring]}}
    async with (
        await connect(base, "/ws/client", tok(viewer)) as w,
        await connect(base, "/ws/vehicle", tok(vh)) as car,
    ):
        assert (await call(w, "subscribe", "s", topics=["zones"]))["ok"] is True
        made = (await api.post("/api/zones", headers=ADMIN, json=zone)).json()
        said = await recv_until(w, lambda f: f["op"] == "event" and f["topic"] == "zones")
        assert said["data"] == {"zone_id": made["zone_id"], "action": "created", "version": 1}
        # a fixed obstacle added or removed: said here too (a console drew none till reload)
        rock = {"name": "rock", "polygon": zone["polygon"]}
        added = (await api.post("/api/obstacles", headers=ADMIN, json=rock)).json()
        said = await recv_until(w, lambda f: f["op"] == "event" and f["topic"] == "zones")
        assert said["data"] == {"obstacle_id": added["obstacle_id"], "action": "created"}
        oid = added["obstacle_id"]
        assert (await api.delete(f"/api/obstacles/{oid}", headers=ADMIN)).is_success
        said = await recv_until(w, lambda f: f["op"] == "event" and f["topic"] == "zones")
        assert said["data"] == {"obstacle_id": oid, "action": "deleted"}
        refused = await call(car, "subscribe", "v", topics=["zones"])
        assert refused["ok"] is False and refused["error"]["code"] == "forbidden"
        written = await call(w, "publish", "p", topic="zones", data={})
        assert written["ok"] is False and written["error"]["code"] == "forbidden"
        below = await call(w, "subscribe", "b", topics=["zones/x"])
        assert below["ok"] is False and "'zones' is one topic" in below["error"]["message"]


async def test_the_events_snapshot_keeps_what_happened_to_control_past_routine_ones(
    base: str, api: httpx.AsyncClient
) -> None:
    """A console opened after 25 missions still lists the grant and the stop before them:
    the snapshot holds the last 20 events and the last 20 that are not routine."""
    vid, _, iid = await _vehicle_with_instance(api)
    user, op = await make_user(api, "operator", [vid])
    grant = {"instance_id": iid, "user": user, "duration_s": 600}
    assert (await api.post("/client/grant_control", headers=ADMIN, json=grant)).is_success
    stop = {"instance_ids": [iid], "command": {"type": "stop", "args": {}}}
    assert (await api.post("/client/submit_control", headers=op, json=stop)).is_success
    for n in range(25):
        go = {"type": "go_to", "args": {"lat": 43.9 + n * 1e-4, "lon": 15.4}}
        r = await api.post("/client/submit_control", headers=op, json={**stop, "command": go})
        assert r.is_success, r.text
    _, viewer = await make_user(api, "viewer", [vid])
    async with await connect(base, "/ws/client", tok(viewer)) as ws:
        ack = await call(ws, "subscribe", "s", topics=[f"vehicle/{vid}/events"])
        assert ack["ok"] is True
        snap = await recv_until(ws, lambda f: f["op"] == "event")
    events = snap["data"]["events"]
    kinds = [e["kind"] for e in events]
    assert "control_grant" in kinds
    stops = [e for e in events if e["kind"] == "command" and e["data"]["type"] == "stop"]
    assert stops, kinds
    assert kinds.count("command") >= 20  # the last 20 as before, the missions among them
    times = [e["at"] for e in events]
    assert times == sorted(times) and len({e["event_id"] for e in events}) == len(events)
