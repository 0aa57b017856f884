"""``fleetctl`` for safety against a real server: zones, failsafes, keeping a lease alive
(and what happens when that client is killed), and verifying the control log."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import sys
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest

from fleet_protocol import parse_ts, utcnow
from server.app import create_app
from server.settings import Settings
from tests.factories import ADMIN, ADMIN_TOKEN, make_user, make_vehicle, sample, start_instance
from tests.fleetctl_run import fleetctl, token_of
from tests.live import serve
from tests.server.commanding import eventually

pytestmark = pytest.mark.usefixtures("store_backend")

SQUARE = {
    "type": "Polygon",
    "coordinates": [
        [[15.40, 43.90], [15.41, 43.90], [15.41, 43.91], [15.40, 43.91], [15.40, 43.90]]
    ],
}


async def test_zones_and_a_failsafe_from_the_command_line(
    make_settings: Callable[..., Settings], tmp_path: Path
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, vh = await make_vehicle(c)
        await start_instance(c, vid, vh)
        shape = tmp_path / "reef.geojson"
        shape.write_text(json.dumps({"type": "Feature", "geometry": SQUARE, "properties": {}}))
        added = await fleetctl(base, ADMIN_TOKEN, "zones", "add", "reef", str(shape), "--json")
        assert added.exit_code == 0, added.output
        zone = json.loads(added.stdout)
        assert zone["kind"] == "no_go" and zone["name"] == "reef"
        listed = await fleetctl(base, ADMIN_TOKEN, "zones")
        assert zone["zone_id"] in listed.stdout and "every vehicle" in listed.stdout
        area = await fleetctl(
            base, ADMIN_TOKEN, "zones", "add", "bay", str(shape), "--kind", "operating_area"
        )
        assert area.exit_code == 1 and "vehicles" in area.stderr  # an area needs a vehicle

        _, manager = await make_user(c, "manager", [vid])
        in_reef = await fleetctl(
            base, token_of(manager), "failsafe", "set", vid, "return_home",
            "--home", "43.905,15.405",
        )  # fmt: skip
        assert in_reef.exit_code == 1 and "home is in no-go zone reef" in in_reef.stderr
        set_ = await fleetctl(
            base, token_of(manager), "failsafe", "set", vid, "return_home", "--after", "45",
            "--home", "43.915,15.405", "--on-breach", "--low-battery", "20",
        )  # fmt: skip
        assert set_.exit_code == 0, set_.output
        assert "return_home to 43.915000,15.405000 after 45 s" in set_.stdout
        assert "also on a zone breach" in set_.stdout and "below 20 %" in set_.stdout
        shown = await fleetctl(base, ADMIN_TOKEN, "failsafe", "show", vid, "--json")
        policy = json.loads(shown.stdout)
        assert policy["failsafe"]["version"] == 1 and policy["acked"] is False
        _, operator = await make_user(c, "operator", [vid])
        refused = await fleetctl(base, token_of(operator), "failsafe", "set", vid, "stop")
        assert refused.exit_code == 1 and "403" in refused.stderr
        bad = await fleetctl(base, ADMIN_TOKEN, "failsafe", "set", vid, "drift")
        assert bad.exit_code == 2 and "none, keep_station, stop, return_home" in bad.stderr

        removed = await fleetctl(base, ADMIN_TOKEN, "zones", "remove", zone["zone_id"])
        assert removed.exit_code == 0
        assert (await c.get("/api/zones", headers=ADMIN)).json()["zones"] == []


async def test_audit_verify_holds_then_fails_after_one_stored_entry_is_altered(
    make_settings: Callable[..., Settings],
) -> None:
    app = create_app(make_settings())
    async with serve(make_settings(), app=app) as base, httpx.AsyncClient(base_url=base) as c:
        vid, vh = await make_vehicle(c)
        iid = (await start_instance(c, vid, vh))["instance_id"]
        empty = await fleetctl(base, ADMIN_TOKEN, "audit", "show", vid)
        assert empty.exit_code == 0 and empty.stdout == "", empty.output
        assert f"no control log entries for {vid} yet" in empty.stderr  # not silence
        user, op = await make_user(c, "operator", [vid])
        grant = {"instance_id": iid, "user": user, "duration_s": 600}
        assert (await c.post("/client/grant_control", headers=ADMIN, json=grant)).is_success
        body = {"instance_ids": [iid], "command": {"type": "go_to", "args": {"lat": 1, "lon": 2}}}
        assert (await c.post("/client/submit_control", headers=op, json=body)).is_success
        store = app.state.services.store["audit"]

        async def two() -> bool:
            return await store.count({"vehicle_id": vid}) >= 2

        await eventually(two)
        ok = await fleetctl(base, ADMIN_TOKEN, "audit", "verify", vid)
        assert ok.exit_code == 0, ok.output
        assert "the chain holds" in ok.stdout and "sha256:" in ok.stdout
        shown = await fleetctl(base, ADMIN_TOKEN, "audit", "show", vid)
        assert "control_grant" in shown.stdout and "go_to" in shown.stdout

        assert await store.update({"_id": f"{vid}/{2:012d}"}, set={"actor": "nobody"})
        broken = await fleetctl(base, ADMIN_TOKEN, "audit", "verify", vid)
        assert broken.exit_code == 1
        assert "breaks at entry 2" in broken.stderr and "does not match its hash" in broken.stderr
        as_json = await fleetctl(base, ADMIN_TOKEN, "audit", "verify", vid, "--json")
        assert json.loads(as_json.stdout)["broken_at_seq"] == 2


async def test_audit_show_prints_an_entry_a_line_within_80_columns(
    make_settings: Callable[..., Settings], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each entry of the control log on one line, its time to the second (``2026-11-27
    09:57:09``): a keep_station ana sent made an 82-character line, broken in two at 80."""
    app = create_app(make_settings())
    async with serve(make_settings(), app=app) as base, httpx.AsyncClient(base_url=base) as c:
        vid, vh = await make_vehicle(c)
        iid = (await start_instance(c, vid, vh))["instance_id"]
        _, op = await make_user(c, "operator", [vid], username="ana")
        grant = {"instance_id": iid, "user": "ana", "duration_s": 600}
        assert (await c.post("/client/grant_control", headers=ADMIN, json=grant)).is_success
        body = {"instance_ids": [iid], "command": {"type": "keep_station", "args": {}}}
        assert (await c.post("/client/submit_control", headers=op, json=body)).is_success
        store = app.state.services.store["audit"]

        async def two() -> bool:
            return await store.count({"vehicle_id": vid}) >= 2

        await eventually(two)
        entries = json.loads(
            (await fleetctl(base, ADMIN_TOKEN, "audit", "show", vid, "--json")).stdout
        )
        monkeypatch.setenv("COLUMNS", "80")
        shown = await fleetctl(base, ADMIN_TOKEN, "audit", "show", vid)
        assert shown.exit_code == 0, shown.output
        lines = shown.stdout.splitlines()
        assert len(lines) == len(entries), shown.stdout
        for line, entry in zip(lines, entries, strict=True):
            at = entry["at"][:19].replace("T", " ")
            assert line.startswith(f"{entry['seq']:>5} {at} {entry['kind']}"), line
            assert len(line) <= 80, line
        assert "keep_station" in lines[-1] and lines[-1].endswith(" ana"), lines


async def test_killing_the_operators_client_ends_the_lease_and_holds_the_vehicle(
    make_settings: Callable[..., Settings],
) -> None:
    # The client starts after the grant: its start-up (a second or two, more on a loaded
    # machine) has to fit well within the operator timeout (3 s lapsed under load).
    lease_s = 6
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, vh = await make_vehicle(c)
        iid = (await start_instance(c, vid, vh))["instance_id"]
        here = {"instance_id": iid, "samples": [sample(1)]}
        assert (await c.post("/upper/update_param", headers=vh, json=here)).is_success
        user, op = await make_user(c, "operator", [vid])
        granted = await fleetctl(
            base, ADMIN_TOKEN, "grant", vid, user, "--operator-timeout", str(lease_s), "--json"
        )
        assert granted.exit_code == 0, granted.output
        assert json.loads(granted.stdout)["operator_timeout_s"] == lease_s
        client = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "remote_client.cli",
            "alive",
            env={**os.environ, "FLEET_SERVER": base, "FLEET_TOKEN": token_of(op)},
            stdout=asyncio.subprocess.DEVNULL,
            stderr=asyncio.subprocess.DEVNULL,
        )
        try:

            async def kept_past_the_timeout() -> bool:
                r = await c.get("/api/events", headers=ADMIN, params={"vehicle_id": vid})
                alive = all(e["kind"] != "control_expired" for e in r.json()["events"])
                lease = (await c.get(f"/api/vehicles/{vid}", headers=ADMIN)).json()["control"]
                assert alive and lease is not None, "the lease lapsed while its client ran"
                return await _seconds_since_grant(c, vid) > 2 * lease_s

            await eventually(kept_past_the_timeout, timeout_s=30)
        finally:
            client.send_signal(signal.SIGKILL)  # killed mid-mission: no goodbye
            await asyncio.wait_for(client.wait(), 10)

        async def lapsed() -> bool:
            r = await c.get(
                "/api/events", headers=ADMIN, params={"vehicle_id": vid, "kind": "control_expired"}
            )
            return any(e["data"]["reason"] == "operator_silent" for e in r.json()["events"])

        await eventually(lapsed, timeout_s=30)
        r = await c.get(
            "/api/events", headers=ADMIN, params={"vehicle_id": vid, "kind": "hold_station"}
        )
        (hold,) = r.json()["events"]
        assert hold["data"]["reason"] == "operator_silent"
        r = await c.get("/upper/get_control", headers=vh, params={"instance_id": iid})
        (cmd,) = r.json()["commands"]
        assert cmd["type"] == "keep_station" and cmd["issued_by"] == "system"


async def _seconds_since_grant(c: httpx.AsyncClient, vehicle_id: str) -> float:
    r = await c.get(
        "/api/events", headers=ADMIN, params={"vehicle_id": vehicle_id, "kind": "control_grant"}
    )
    (grant,) = r.json()["events"]
    return (utcnow() - parse_ts(grant["at"])).total_seconds()


async def test_vehicles_says_since_when_each_alarm_is_so(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, vh = await make_vehicle(c)
        put = await c.put(
            f"/api/vehicles/{vid}/failsafe", headers=ADMIN, json={"low_battery_pct": 20.0}
        )
        assert put.status_code == 200, put.text
        iid = (await start_instance(c, vid, vh))["instance_id"]
        raised = utcnow()
        body = {"instance_id": iid, "samples": [sample(1, ts=raised, battery_pct=15.0)]}
        assert (await c.post("/upper/update_param", headers=vh, json=body)).is_success

        async def alarmed() -> bool:
            view = (await c.get(f"/api/vehicles/{vid}", headers=ADMIN)).json()
            return bool(view["alarms"])

        await eventually(alarmed)
        name = (await c.get(f"/api/vehicles/{vid}", headers=ADMIN)).json()["name"]
        table = await fleetctl(base, ADMIN_TOKEN, "vehicles")
        assert table.exit_code == 0, table.output
        assert (
            f"ALARM {name} ({vid}): battery low: 15 % (alarm below 20 %) since {raised:%H:%M:%S}Z\n"
        ) in table.stdout
