"""``fleetctl`` against a real server: tables for people, JSON for scripts, errors on stderr."""

from __future__ import annotations

import asyncio
import csv
import json
import os
import re
import sys
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest

from fleet_protocol import parse_ts
from server.settings import Settings
from tests.factories import ADMIN, ADMIN_TOKEN, make_user, make_vehicle, sample, start_instance
from tests.fleetctl_run import fleetctl as _fleetctl
from tests.live import free_port, serve

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


async def test_an_operator_lists_is_refused_then_granted_and_commands(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, vh = await make_vehicle(c)
        iid = (await start_instance(c, vid, vh))["instance_id"]
        first = {"instance_id": iid, "samples": [sample(1)]}
        assert (await c.post("/upper/update_param", headers=vh, json=first)).is_success
        _, op = await make_user(c, "operator", vehicles=[vid], username="olga")
        op_token = op["Authorization"].removeprefix("Bearer ")

        listed = await _fleetctl(base, op_token, "vehicles", "--json")
        assert listed.exit_code == 0, listed.output
        assert [v["instance_id"] for v in json.loads(listed.stdout)["vehicles"]] == [iid]
        table = await _fleetctl(base, op_token, "vehicles")
        assert vid in table.stdout and "online" in table.stdout
        row = next(line for line in table.stdout.splitlines() if vid in line)
        assert "43.94000,15.44000" in row  # whole, not cut to fit (the name may wrap)

        refused = await _fleetctl(base, op_token, "goto", iid, "43.95", "15.45", "--json")
        assert refused.exit_code == 1
        assert refused.stdout == ""  # a script reading --json output sees no error text
        assert "409 control_not_held" in refused.stderr and iid in refused.stderr

        granted = await _fleetctl(base, ADMIN_TOKEN, "grant", iid, "olga", "--json")
        assert granted.exit_code == 0, granted.output
        assert json.loads(granted.stdout)["holder"] == "olga"

        sent = await _fleetctl(base, op_token, "goto", iid, "-33.95", "-15.45", "--json")
        assert sent.exit_code == 0, sent.output  # negative coordinates are not options
        command = json.loads(sent.stdout)["commands"][0]
        assert command["instance_id"] == iid and command["status"] == "queued"

        local = await _fleetctl(base, op_token, "goto", iid, "95", "15.45")
        assert local.exit_code == 2 and "LAT is a latitude" in local.stderr  # nothing sent
        bad = await _fleetctl(base, op_token, "goto", iid, "43.9", "15.45", "--speed", "60")
        assert bad.exit_code == 2 and "--speed is at most 50" in bad.stderr  # nor this
        long = await _fleetctl(base, op_token, "path", iid, *["43.9,15.45"] * 1001)
        assert long.exit_code == 1 and "422 invalid" in long.stderr  # the server's refusal
        assert "command.args.waypoints" in long.stderr  # each detail on its own line

        everyone = await _fleetctl(base, ADMIN_TOKEN, "stop", "--json")
        assert everyone.exit_code == 0, everyone.output
        [stop] = json.loads(everyone.stdout)["commands"]
        assert stop["instance_id"] == iid
        sent = (await c.get(f"/api/commands/{stop['command_id']}", headers=ADMIN)).json()
        waits = parse_ts(sent["expires_at"]) - parse_ts(sent["issued_at"])
        assert waits.total_seconds() == 3600  # a stop waits for a vehicle out of reach


async def test_an_unreachable_server_is_exit_code_3(make_settings: Callable[..., Settings]) -> None:
    async with serve(make_settings()) as base:
        pass  # stopped: its port is closed now
    gone = await _fleetctl(base, ADMIN_TOKEN, "vehicles")
    assert gone.exit_code == 3 and "cannot reach" in gone.stderr and gone.stdout == ""


async def test_missions_requests_and_the_lease_from_the_command_line(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, vh = await make_vehicle(c)
        iid = (await start_instance(c, vid, vh))["instance_id"]
        _, op = await make_user(c, "operator", vehicles=[vid], username="piet")
        op_token = op["Authorization"].removeprefix("Bearer ")

        asked = await _fleetctl(base, op_token, "request", iid, "--json")
        assert asked.exit_code == 0, asked.output
        pending = await _fleetctl(base, ADMIN_TOKEN, "requests", iid)
        assert pending.exit_code == 0 and "piet" in pending.stdout
        assert (await _fleetctl(base, ADMIN_TOKEN, "grant", iid, "piet")).exit_code == 0
        shorter = await _fleetctl(base, ADMIN_TOKEN, "grant", iid, "piet", "--duration", "60")
        assert shorter.exit_code == 0 and "a grant never shortens a lease" in shorter.stdout

        held = await _fleetctl(base, op_token, "station", iid, "--radius", "5", "--json")
        assert held.exit_code == 0, held.output
        one_sided = await _fleetctl(base, op_token, "station", iid, "--lat", "43.9")
        assert one_sided.exit_code == 2 and "--lat and --lon" in one_sided.stderr
        route = ["43.941,15.441", "-43.942,-15.442"]
        followed = await _fleetctl(base, op_token, "path", iid, *route, "--speed", "1.5", "--json")
        assert followed.exit_code == 0, followed.output
        path_id = json.loads(followed.stdout)["commands"][0]["command_id"]
        garbled = await _fleetctl(base, op_token, "path", iid, "43.9;15.4")
        assert garbled.exit_code == 2 and "LAT,LON" in garbled.stderr

        listed = await _fleetctl(base, op_token, "commands", iid, "--json")
        kinds = {cmd["command_id"]: cmd for cmd in json.loads(listed.stdout)["commands"]}
        assert kinds[path_id]["type"] == "follow_path"
        assert kinds[path_id]["args"]["waypoints"][1] == {"lat": -43.942, "lon": -15.442}
        assert {cmd["args"].get("radius_m") for cmd in kinds.values()} >= {5.0}
        table = await _fleetctl(base, op_token, "commands", iid)
        assert path_id in table.stdout and "control mode" in table.stdout

        cancelled = await _fleetctl(base, op_token, "cancel", path_id, "--json")
        assert cancelled.exit_code == 0 and json.loads(cancelled.stdout)["status"] == "cancelled"

        released = await _fleetctl(base, op_token, "release", iid)
        assert released.exit_code == 0 and "released" in released.stdout
        after = await _fleetctl(base, op_token, "station", iid)
        assert after.exit_code == 1 and "control_not_held" in after.stderr
        assert (await _fleetctl(base, ADMIN_TOKEN, "grant", iid, "piet")).exit_code == 0
        revoked = await _fleetctl(base, ADMIN_TOKEN, "revoke", iid, "--json")
        assert revoked.exit_code == 0 and json.loads(revoked.stdout)["revoked"] is True
        nobody = await _fleetctl(base, ADMIN_TOKEN, "revoke", iid)
        assert nobody.exit_code == 0 and f"nobody held {iid}" in nobody.stdout
        not_a_manager = await _fleetctl(base, op_token, "revoke", iid)
        assert not_a_manager.exit_code == 1 and "403" in not_a_manager.stderr

        assert (await _fleetctl(base, op_token, "request", vid)).exit_code == 0
        denied = await _fleetctl(base, ADMIN_TOKEN, "deny", vid, "piet", "--reason", "divers")
        assert denied.exit_code == 0 and "piet's request" in denied.stdout, denied.output
        assert "piet" not in (await _fleetctl(base, ADMIN_TOKEN, "requests", vid)).stdout
        again = await _fleetctl(base, ADMIN_TOKEN, "deny", vid, "piet")
        assert again.exit_code == 1 and "404" in again.stderr  # nothing pending now


async def test_watch_prints_the_current_state_then_changes(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, vh = await make_vehicle(c)
        iid = (await start_instance(c, vid, vh))["instance_id"]
        seq = 1
        r = await c.post(
            "/upper/update_param", headers=vh, json={"instance_id": iid, "samples": [sample(seq)]}
        )
        assert r.status_code == 200
        topic = f"vehicle/{vid}/telemetry"
        watching = asyncio.create_task(
            _fleetctl(base, ADMIN_TOKEN, "watch", topic, "--count", "2", "--json")
        )
        async with asyncio.timeout(20):
            while not watching.done():  # samples until the watcher has seen a change
                seq += 1
                body = {"instance_id": iid, "samples": [sample(seq)]}
                assert (await c.post("/upper/update_param", headers=vh, json=body)).is_success
                await asyncio.wait({watching}, timeout=0.05)
        result = watching.result()
        assert result.exit_code == 0, result.output
        first, second = (json.loads(line) for line in result.stdout.splitlines())
        assert first["topic"] == topic and first["snapshot"] is True
        assert second.get("snapshot") is None and second["data"]["seq"] > first["data"]["seq"]

        fleet = await _fleetctl(base, ADMIN_TOKEN, "watch", "--seconds", "0.5")
        assert fleet.exit_code == 0, fleet.output
        assert fleet.stdout.startswith(f"current fleet {vid} online 43.94000,15.44000")

        _, viewer = await make_user(c, "viewer", vehicles=[])
        blind = await _fleetctl(
            base, viewer["Authorization"].removeprefix("Bearer "), "watch", topic, "--seconds", "5"
        )
        assert blind.exit_code == 1 and "forbidden" in blind.stderr and blind.stdout == ""
        nobody = await _fleetctl(base, "fct_not-a-token-at-all-0000000000", "watch")
        assert nobody.exit_code == 1 and "refused" in nobody.stderr


async def test_export_writes_every_sample_page_by_page(
    make_settings: Callable[..., Settings], tmp_path: Path
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, vh = await make_vehicle(c)
        iid = (await start_instance(c, vid, vh))["instance_id"]
        samples = [sample(seq, depth_m=1.5) for seq in range(1, 26)]
        samples[3]["data"] = {"sonar": "ok"}
        body = {"instance_id": iid, "samples": samples}
        assert (await c.post("/upper/update_param", headers=vh, json=body)).is_success

        lines = await _fleetctl(base, ADMIN_TOKEN, "export", vid, "--page", "10")
        assert lines.exit_code == 0, lines.output
        rows = [json.loads(line) for line in lines.stdout.splitlines()]
        assert [r["seq"] for r in rows] == list(range(1, 26))  # three pages, none twice
        assert rows[3]["data"] == {"sonar": "ok"} and rows[0]["depth_m"] == 1.5

        target = tmp_path / "track.csv"
        written = await _fleetctl(
            base, ADMIN_TOKEN, "export", vid, "--format", "csv", "-o", str(target), "--page", "7"
        )
        assert written.exit_code == 0 and "25 samples written" in written.stderr
        table = list(csv.DictReader(target.open()))
        assert [int(r["seq"]) for r in table] == list(range(1, 26))
        assert json.loads(table[3]["data"]) == {"sonar": "ok"} and table[0]["data"] == ""
        assert float(table[0]["depth_m"]) == 1.5
        by_ending = tmp_path / "again.CSV"  # no --format: the file's ending chooses csv
        again = await _fleetctl(base, ADMIN_TOKEN, "export", vid, "-o", str(by_ending))
        assert again.exit_code == 0, again.output
        assert by_ending.read_text() == target.read_text()

        unknown = await _fleetctl(base, ADMIN_TOKEN, "export", "no-such-vehicle")
        assert unknown.exit_code == 1 and "404" in unknown.stderr
        wrong = await _fleetctl(base, ADMIN_TOKEN, "export", vid, "--format", "xml")
        assert wrong.exit_code == 2 and "jsonl, csv" in wrong.stderr


async def test_watch_takes_a_lost_link_up_again(make_settings: Callable[..., Settings]) -> None:
    settings, port = make_settings(), free_port()
    watcher: asyncio.subprocess.Process | None = None
    try:
        async with asyncio.timeout(60):
            async with serve(settings, port=port) as base, httpx.AsyncClient(base_url=base) as c:
                vid, vh = await make_vehicle(c)
                await start_instance(c, vid, vh)
                env = {**os.environ, "FLEET_SERVER": base, "FLEET_TOKEN": ADMIN_TOKEN}
                watcher = await asyncio.create_subprocess_exec(
                    sys.executable, "-m", "remote_client.cli", "watch", "--count", "2", "--json",
                    env=env, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
                )  # fmt: skip
                assert watcher.stdout is not None and watcher.stderr is not None
                first = json.loads(await watcher.stdout.readline())
            # The server is gone; the watcher waits, then finds it back on the same port.
            async with serve(settings, port=port):
                second = json.loads(await watcher.stdout.readline())
                assert await watcher.wait() == 0
    finally:
        if watcher is not None and watcher.returncode is None:
            watcher.kill()
            await watcher.wait()
    assert first["topic"] == second["topic"] == "fleet"
    assert first["snapshot"] is True and second["snapshot"] is True  # the current state, again
    assert vid in json.dumps(second["data"])
    assert "link lost" in (await watcher.stderr.read()).decode()


async def test_watch_stops_quietly_when_its_output_is_closed(
    make_settings: Callable[..., Settings],
) -> None:
    """``fleetctl watch ... | head -1``: once head has gone, the next event ends the
    watch at once, exit 141 (as SIGPIPE would), no traceback, no link taken for lost."""
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, vh = await make_vehicle(c)
        iid = (await start_instance(c, vid, vh))["instance_id"]
        seq = 1
        body = {"instance_id": iid, "samples": [sample(seq)]}
        assert (await c.post("/upper/update_param", headers=vh, json=body)).is_success
        read_end, write_end = os.pipe()
        env = {**os.environ, "FLEET_SERVER": base, "FLEET_TOKEN": ADMIN_TOKEN}
        watcher = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "remote_client.cli", "watch", f"vehicle/{vid}/telemetry",
            env=env, stdout=write_end, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        os.close(write_end)
        try:
            with os.fdopen(read_end, "rb") as head:  # head -1: a line, then gone
                first = await asyncio.to_thread(head.readline)
            exited = asyncio.ensure_future(watcher.wait())
            async with asyncio.timeout(20):
                while not exited.done():  # events until it notices
                    seq += 1
                    body = {"instance_id": iid, "samples": [sample(seq)]}
                    assert (await c.post("/upper/update_param", headers=vh, json=body)).is_success
                    await asyncio.wait({exited}, timeout=0.05)
        finally:
            if watcher.returncode is None:
                watcher.kill()
                await watcher.wait()
        assert watcher.stderr is not None
        stderr = (await watcher.stderr.read()).decode()
    assert first.startswith(b"current ") and vid.encode() in first
    assert watcher.returncode == 141, stderr
    assert stderr == ""  # neither "link lost" nor a traceback


async def test_export_stops_quietly_when_its_output_is_closed(
    make_settings: Callable[..., Settings],
) -> None:
    """``fleetctl export ... | head -1`` on more samples than a pipe holds: exit 141, quiet."""
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, vh = await make_vehicle(c)
        iid = (await start_instance(c, vid, vh))["instance_id"]
        for first_seq in range(1, 2001, 200):  # ~300 kB of JSON lines, a pipe holds 64 kB
            body = {"instance_id": iid, "samples": [sample(first_seq + i) for i in range(200)]}
            assert (await c.post("/upper/update_param", headers=vh, json=body)).is_success
        read_end, write_end = os.pipe()
        env = {**os.environ, "FLEET_SERVER": base, "FLEET_TOKEN": ADMIN_TOKEN}
        exporter = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "remote_client.cli", "export", vid, "--page", "100",
            env=env, stdout=write_end, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        os.close(write_end)
        try:
            with os.fdopen(read_end, "rb") as head:
                first = await asyncio.to_thread(head.readline)
            async with asyncio.timeout(20):
                _, stderr = await exporter.communicate()
        finally:
            if exporter.returncode is None:
                exporter.kill()
                await exporter.wait()
    assert json.loads(first)["seq"] == 1
    assert exporter.returncode == 141, stderr
    assert stderr == b""


async def _named(c: httpx.AsyncClient, vid: str, vh: dict[str, str], name: str) -> str:
    """Start an instance that announces ``name`` as the vehicle's display name."""
    body = {"vehicle_id": vid, "name": name, "vehicle_type": "usv",
            "capabilities": ["stop", "go_to", "keep_station", "follow_path"]}  # fmt: skip
    r = await c.post("/upper/start_instance", headers=vh, json=body)
    assert r.status_code == 200, r.text
    return str(r.json()["instance_id"])


async def test_a_vehicle_name_works_wherever_an_id_does(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, vh = await make_vehicle(c)
        iid = await _named(c, vid, vh, "H2OmniX Alpha")
        twin_a, th = await make_vehicle(c)
        await _named(c, twin_a, th, "Twin")
        twin_b, tbh = await make_vehicle(c)
        await _named(c, twin_b, tbh, "twin")
        _, op = await make_user(c, "operator", vehicles=[vid], username="nora")
        nora = op["Authorization"].removeprefix("Bearer ")

        asked = await _fleetctl(base, nora, "request", "H2OmniX Alpha", "--json")
        assert asked.exit_code == 0, asked.output
        assert json.loads(asked.stdout)["instance_id"] == iid
        pending = await _fleetctl(base, ADMIN_TOKEN, "requests", "h2omnix alpha", "--json")
        assert [r["username"] for r in json.loads(pending.stdout)["requests"]] == ["nora"]
        granted = await _fleetctl(base, ADMIN_TOKEN, "grant", "H2OmniX Alpha", "nora")
        assert granted.exit_code == 0 and f"nora holds {iid}" in granted.stdout

        went = await _fleetctl(base, nora, "goto", "H2OmniX Alpha", "43.95", "-15.45", "--json")
        assert went.exit_code == 0, went.output
        go_id = json.loads(went.stdout)["commands"][0]["command_id"]
        held = await _fleetctl(base, nora, "station", vid, "--json")  # the id works as before
        assert json.loads(held.stdout)["commands"][0]["instance_id"] == iid
        followed = await _fleetctl(base, nora, "path", "H2OmniX Alpha", "43.9,15.4", "--json")
        assert followed.exit_code == 0, followed.output
        assert (await _fleetctl(base, nora, "stop", "H2OmniX Alpha")).exit_code == 0

        listed = await _fleetctl(base, nora, "commands", "H2OmniX Alpha")
        assert listed.exit_code == 0, listed.output
        row = next(line for line in listed.stdout.splitlines() if go_id in line)
        assert "superseded" in row and "cancelled" not in row  # a stop took its place
        as_json = json.loads((await _fleetctl(base, nora, "commands", iid, "--json")).stdout)
        assert {c["status"] for c in as_json["commands"] if c["type"] != "stop"} == {"cancelled"}

        assert (await _fleetctl(base, nora, "release", "H2OmniX Alpha")).exit_code == 0
        assert (await _fleetctl(base, ADMIN_TOKEN, "grant", vid, "nora")).exit_code == 0
        assert (await _fleetctl(base, ADMIN_TOKEN, "revoke", "H2OmniX Alpha")).exit_code == 0

        unknown = await _fleetctl(base, nora, "goto", "Zulu", "43.9", "15.4")
        assert unknown.exit_code == 1 and "404 not_found" in unknown.stderr
        assert "'Zulu'" in unknown.stderr and unknown.stdout == ""
        hidden = await _fleetctl(base, nora, "stop", "Twin")  # not hers: not found
        assert hidden.exit_code == 1 and "not_found" in hidden.stderr
        ambiguous = await _fleetctl(base, ADMIN_TOKEN, "stop", "TWIN")
        assert ambiguous.exit_code == 2 and "ambiguous_name" in ambiguous.stderr
        assert twin_a in ambiguous.stderr and twin_b in ambiguous.stderr
        exact = await _fleetctl(base, ADMIN_TOKEN, "stop", "Twin", "--json")
        assert exact.exit_code == 0  # the exact name is one vehicle


async def test_watch_prints_a_readable_line_per_event_and_takes_names(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, vh = await make_vehicle(c)
        iid = await _named(c, vid, vh, "Kestrel")
        seq = 1
        body = {"instance_id": iid, "samples": [sample(seq, speed_mps=1.5, battery_pct=80.0)]}
        assert (await c.post("/upper/update_param", headers=vh, json=body)).is_success
        watching = asyncio.create_task(
            _fleetctl(base, ADMIN_TOKEN, "watch", "vehicle/Kestrel/telemetry", "--count", "2")
        )
        async with asyncio.timeout(20):
            while not watching.done():
                seq += 1
                body = {"instance_id": iid, "samples": [sample(seq, speed_mps=1.5, battery_pct=80)]}
                assert (await c.post("/upper/update_param", headers=vh, json=body)).is_success
                await asyncio.wait({watching}, timeout=0.05)
        result = watching.result()
        assert result.exit_code == 0, result.output
        first, second = result.stdout.splitlines()
        # (the samples' times are the factory's, long past: the server calls them replayed)
        line = r"{} {} telemetry #\d+ 43\.94000,15\.44000 1\.5 m/s 80% battery( \(replayed\))?"
        assert re.fullmatch(line.format("current", vid), first), first  # the latest sample
        assert re.fullmatch(line.format(r"\d\d:\d\d:\d\dZ", vid), second), second
        assert "{" not in result.stdout  # lines for people, not JSON
        # a vehicle nobody registered: said at once, not a silent wait
        nothing = await _fleetctl(base, ADMIN_TOKEN, "watch", "vehicle/nosuch/telemetry",
                                  "--seconds", "0.5")  # fmt: skip
        assert nothing.exit_code == 0 and "no vehicle 'nosuch'" in nothing.stderr
