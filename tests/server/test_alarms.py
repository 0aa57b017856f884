"""A vehicle's alarms in the fleet view (``VehicleView.alarms``, an extension): what is
wrong with it now, from its telemetry and its mode, on ``GET /api/vehicles`` and live on
the ``fleet`` topic; gone when it is no longer so."""

from __future__ import annotations

import re
from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any

import httpx
import pytest

from server.settings import Settings
from tests.factories import ADMIN, make_vehicle, sample
from tests.fleetctl_run import fleetctl
from tests.live import call, connect, recv_until, serve
from tests.server.test_obstacles import PIER, at, polygon

pytestmark = pytest.mark.usefixtures("store_backend")

CAPS = ["stop", "go_to", "keep_station", "follow_path"]


def kinds(view: dict[str, Any]) -> list[str]:
    return [a["kind"] for a in view["alarms"]]


async def test_alarms_follow_the_vehicle_s_zones_battery_and_failsafe(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        made = await c.post(
            "/api/zones",
            headers=ADMIN,
            json={"name": "pier 3", "kind": "no_go", "polygon": polygon(PIER)},
        )
        assert made.status_code == 201, made.text
        vid, vh = await make_vehicle(c)
        put = await c.put(
            f"/api/vehicles/{vid}/failsafe",
            headers=ADMIN,
            json={"action": "keep_station", "low_battery_pct": 20.0},
        )
        assert put.status_code == 200, put.text
        started = await c.post(
            "/upper/start_instance", headers=vh, json={"vehicle_id": vid, "capabilities": CAPS}
        )
        iid = started.json()["instance_id"]

        async def report(seq: int, x: float, battery: float) -> None:
            lat, lon = at(x, 0).values()
            body = {
                "instance_id": iid,
                "samples": [
                    sample(seq, ts=datetime.now(UTC), lat=lat, lon=lon, battery_pct=battery)
                ],
            }
            r = await c.post("/upper/update_param", headers=vh, json=body)
            assert r.status_code == 200, r.text

        async def view() -> dict[str, Any]:
            r = await c.get(f"/api/vehicles/{vid}", headers=ADMIN)
            assert r.status_code == 200, r.text
            got: dict[str, Any] = r.json()
            return got

        await report(1, 0, 80.0)  # at home, battery fine
        assert (await view())["alarms"] == []

        token = ADMIN["Authorization"].removeprefix("Bearer ")
        async with await connect(base, "/ws/client", token) as ws:
            await call(ws, "subscribe", "s", topics=["fleet"])
            await recv_until(ws, lambda f: f["op"] == "event")  # the snapshot

            await report(2, 50, 15.0)  # into the pier, battery low
            pushed = await recv_until(
                ws,
                lambda f: (
                    f["op"] == "event"
                    and any(len(v.get("alarms", [])) == 2 for v in f["data"]["vehicles"])
                ),
            )
            [live] = pushed["data"]["vehicles"]
            assert kinds(live) == ["no_go_zone", "low_battery"]
            alarms = (await view())["alarms"]
            assert alarms[0].pop("since")  # since when: test_alarm_since
            assert alarms[0] == {
                "kind": "no_go_zone",
                "message": "inside no-go zone pier 3",
                "zone_id": made.json()["zone_id"],
            }
            assert alarms[1]["message"] == "battery low: 15 % (alarm below 20 %)"

            acked = await c.post(
                "/upper/update_fbmessage",
                headers=vh,
                json={"instance_id": iid, "acks": [], "control_mode": "failsafe"},
            )
            assert acked.status_code == 200, acked.text
            await recv_until(
                ws,
                lambda f: (
                    f["op"] == "event"
                    and any("failsafe" in kinds(v) for v in f["data"]["vehicles"] if "alarms" in v)
                ),
            )
            listed = await c.get("/api/vehicles", headers=ADMIN)
            [row] = [v for v in listed.json()["vehicles"] if v["vehicle_id"] == vid]
            assert kinds(row) == ["failsafe", "no_go_zone", "low_battery"]
            assert row["alarms"][0]["message"] == "in failsafe: keep station"
            table = await fleetctl(base, token, "vehicles")
            assert table.exit_code == 0, table.output
            assert re.search(
                rf"ALARM {vid.upper()} \({vid}\): in failsafe: keep station; inside no-go zone "
                r"pier 3 since \d\d:\d\d:\d\dZ; battery low: 15 % \(alarm below 20 %\) "
                r"since \d\d:\d\d:\d\dZ\n",
                table.stdout,
            ), table.stdout

            await c.post(
                "/upper/update_fbmessage",
                headers=vh,
                json={"instance_id": iid, "acks": [], "control_mode": "idle"},
            )
            await report(3, 0, 30.0)  # out of the pier, charged past the threshold and 2 more
            await recv_until(
                ws,
                lambda f: (
                    f["op"] == "event" and any(v.get("alarms") == [] for v in f["data"]["vehicles"])
                ),
            )
            assert (await view())["alarms"] == []

        await c.post("/upper/finish_instance", headers=vh, json={"instance_id": iid})
        assert (await view())["alarms"] == []
