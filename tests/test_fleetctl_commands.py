"""``fleetctl`` commanding against a real server: listing the vehicles, a command refused
then granted, missions, requests for control and the lease, a vehicle named instead of
its id, and an unreachable server; tables for people, JSON for scripts, errors on
stderr."""

from __future__ import annotations

import json
import re
from collections.abc import Callable

import pytest

from fleet_protocol import parse_ts
from server.settings import Settings
from tests.factories import ADMIN, ADMIN_TOKEN, make_user, make_vehicle, sample, start_instance
from tests.fleetctl_run import fleetctl, served_vehicle
from tests.live import serve

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


async def test_an_operator_lists_is_refused_then_granted_and_commands(
    make_settings: Callable[..., Settings],
) -> None:
    async with served_vehicle(make_settings()) as (base, c, vid, vh, iid):
        first = {"instance_id": iid, "samples": [sample(1)]}
        assert (await c.post("/upper/update_param", headers=vh, json=first)).is_success
        _, op = await make_user(c, "operator", vehicles=[vid], username="olga")
        op_token = op["Authorization"].removeprefix("Bearer ")

        listed = await fleetctl(base, op_token, "vehicles", "--json")
        assert listed.exit_code == 0, listed.output
        assert [v["instance_id"] for v in json.loads(listed.stdout)["vehicles"]] == [iid]
        table = await fleetctl(base, op_token, "vehicles")
        assert vid in table.stdout and "online" in table.stdout
        row = next(line for line in table.stdout.splitlines() if vid in line)
        assert "43.94000,15.44000" in row  # whole, not cut to fit (the name may wrap)

        refused = await fleetctl(base, op_token, "goto", iid, "43.95", "15.45", "--json")
        assert refused.exit_code == 1
        assert refused.stdout == ""  # a script reading --json output sees no error text
        assert "409 control_not_held" in refused.stderr and iid in refused.stderr

        granted = await fleetctl(base, ADMIN_TOKEN, "grant", iid, "olga", "--json")
        assert granted.exit_code == 0, granted.output
        assert json.loads(granted.stdout)["holder"] == "olga"

        sent = await fleetctl(base, op_token, "goto", iid, "-33.95", "-15.45", "--json")
        assert sent.exit_code == 0, sent.output  # negative coordinates are not options
        command = json.loads(sent.stdout)["commands"][0]
        assert command["instance_id"] == iid and command["status"] == "queued"

        local = await fleetctl(base, op_token, "goto", iid, "95", "15.45")
        assert local.exit_code == 2 and "LAT is a latitude" in local.stderr  # nothing sent
        bad = await fleetctl(base, op_token, "goto", iid, "43.9", "15.45", "--speed", "60")
        assert bad.exit_code == 2 and "--speed is at most 50" in bad.stderr  # nor this
        long = await fleetctl(base, op_token, "path", iid, *["43.9,15.45"] * 1001)
        assert long.exit_code == 1 and "422 invalid" in long.stderr  # the server's refusal
        assert "command.args.waypoints" in long.stderr  # each detail on its own line

        everyone = await fleetctl(base, ADMIN_TOKEN, "stop", "--json")
        assert everyone.exit_code == 0, everyone.output
        [stop] = json.loads(everyone.stdout)["commands"]
        assert stop["instance_id"] == iid
        sent = (await c.get(f"/api/commands/{stop['command_id']}", headers=ADMIN)).json()
        waits = parse_ts(sent["expires_at"]) - parse_ts(sent["issued_at"])
        assert waits.total_seconds() == 3600  # a stop waits for a vehicle out of reach


async def test_an_unreachable_server_is_exit_code_3(make_settings: Callable[..., Settings]) -> None:
    async with serve(make_settings()) as base:
        pass  # stopped: its port is closed now
    gone = await fleetctl(base, ADMIN_TOKEN, "vehicles")
    assert gone.exit_code == 3 and "cannot reach" in gone.stderr and gone.stdout == ""


async def test_missions_requests_and_the_lease_from_the_command_line(
    make_settings: Callable[..., Settings],
) -> None:
    async with served_vehicle(make_settings()) as (base, c, vid, _, iid):
        _, op = await make_user(c, "operator", vehicles=[vid], username="piet")
        op_token = op["Authorization"].removeprefix("Bearer ")

        asked = await fleetctl(base, op_token, "request", iid, "--json")
        assert asked.exit_code == 0, asked.output
        pending = await fleetctl(base, ADMIN_TOKEN, "requests", iid)
        assert pending.exit_code == 0 and "piet" in pending.stdout
        assert "piet" not in (await fleetctl(base, op_token, "requests")).stdout  # answers none
        mine = await fleetctl(base, op_token, "requests", "--mine", "--json")
        (own,) = json.loads(mine.stdout)["requests"]
        assert own["request_id"] == json.loads(asked.stdout)["request_id"], mine.output
        assert own["expires_at"] == json.loads(asked.stdout)["expires_at"]
        assert (await fleetctl(base, ADMIN_TOKEN, "grant", iid, "piet")).exit_code == 0
        answered = await fleetctl(base, op_token, "requests", "--mine", "--json")
        assert json.loads(answered.stdout)["requests"] == [], answered.output
        shorter = await fleetctl(base, ADMIN_TOKEN, "grant", iid, "piet", "--duration", "60")
        assert shorter.exit_code == 0 and "a grant never shortens a lease" in shorter.stdout

        held = await fleetctl(base, op_token, "station", iid, "--radius", "5", "--json")
        assert held.exit_code == 0, held.output
        one_sided = await fleetctl(base, op_token, "station", iid, "--lat", "43.9")
        assert one_sided.exit_code == 2 and "--lat and --lon" in one_sided.stderr
        route = ["43.941,15.441", "-43.942,-15.442"]
        followed = await fleetctl(base, op_token, "path", iid, *route, "--speed", "1.5", "--json")
        assert followed.exit_code == 0, followed.output
        path_id = json.loads(followed.stdout)["commands"][0]["command_id"]
        garbled = await fleetctl(base, op_token, "path", iid, "43.9;15.4")
        assert garbled.exit_code == 2 and "LAT,LON" in garbled.stderr

        listed = await fleetctl(base, op_token, "commands", iid, "--json")
        kinds = {cmd["command_id"]: cmd for cmd in json.loads(listed.stdout)["commands"]}
        assert kinds[path_id]["type"] == "follow_path"
        assert kinds[path_id]["args"]["waypoints"][1] == {"lat": -43.942, "lon": -15.442}
        assert {cmd["args"].get("radius_m") for cmd in kinds.values()} >= {5.0}
        table = await fleetctl(base, op_token, "commands", iid)
        assert path_id in table.stdout and "control mode" in table.stdout
        assert "keep_station" in table.stdout and "follow_path" in table.stdout  # 80 columns

        cancelled = await fleetctl(base, op_token, "cancel", path_id, "--json")
        assert cancelled.exit_code == 0 and json.loads(cancelled.stdout)["status"] == "cancelled"

        released = await fleetctl(base, op_token, "release", iid)
        assert released.exit_code == 0 and "released" in released.stdout
        after = await fleetctl(base, op_token, "station", iid)
        assert after.exit_code == 1 and "control_not_held" in after.stderr
        assert (await fleetctl(base, ADMIN_TOKEN, "grant", iid, "piet")).exit_code == 0
        taken = await fleetctl(base, ADMIN_TOKEN, "grant", iid, "admin")
        assert taken.exit_code == 0 and "piet's lease ended" in taken.stdout, taken.output
        revoked = await fleetctl(base, ADMIN_TOKEN, "revoke", iid, "--json")
        assert revoked.exit_code == 0 and json.loads(revoked.stdout)["revoked"] is True
        nobody = await fleetctl(base, ADMIN_TOKEN, "revoke", iid)
        assert nobody.exit_code == 0 and f"nobody held {vid}" in nobody.stdout  # named as its id
        not_a_manager = await fleetctl(base, op_token, "revoke", iid)
        assert not_a_manager.exit_code == 1 and "403" in not_a_manager.stderr

        assert (await fleetctl(base, op_token, "request", vid)).exit_code == 0
        denied = await fleetctl(base, ADMIN_TOKEN, "deny", vid, "piet", "--reason", "divers")
        assert denied.exit_code == 0 and "piet's request" in denied.stdout, denied.output
        assert "piet" not in (await fleetctl(base, ADMIN_TOKEN, "requests", vid)).stdout
        again = await fleetctl(base, ADMIN_TOKEN, "deny", vid, "piet")
        assert again.exit_code == 1 and "404" in again.stderr  # nothing pending now


async def test_a_vehicle_name_works_wherever_an_id_does(
    make_settings: Callable[..., Settings],
) -> None:
    async with served_vehicle(make_settings(), name="H2OmniX Alpha") as (base, c, vid, _, iid):
        twin_a, th = await make_vehicle(c)
        await start_instance(c, twin_a, th, name="Twin")
        twin_b, tbh = await make_vehicle(c)
        await start_instance(c, twin_b, tbh, name="twin")
        _, op = await make_user(c, "operator", vehicles=[vid], username="nora")
        nora = op["Authorization"].removeprefix("Bearer ")

        asked = await fleetctl(base, nora, "request", "H2OmniX Alpha", "--json")
        assert asked.exit_code == 0, asked.output
        assert json.loads(asked.stdout)["instance_id"] == iid
        pending = await fleetctl(base, ADMIN_TOKEN, "requests", "h2omnix alpha", "--json")
        assert [r["username"] for r in json.loads(pending.stdout)["requests"]] == ["nora"]
        granted = await fleetctl(base, ADMIN_TOKEN, "grant", "H2OmniX Alpha", "nora")
        assert granted.exit_code == 0 and f"nora holds H2OmniX Alpha ({vid})" in granted.stdout

        went = await fleetctl(base, nora, "goto", "H2OmniX Alpha", "43.95", "-15.45", "--json")
        assert went.exit_code == 0, went.output
        go_id = json.loads(went.stdout)["commands"][0]["command_id"]
        held = await fleetctl(base, nora, "station", vid, "--json")  # the id works as before
        assert json.loads(held.stdout)["commands"][0]["instance_id"] == iid
        followed = await fleetctl(base, nora, "path", "H2OmniX Alpha", "43.9,15.4", "--json")
        assert followed.exit_code == 0, followed.output
        assert (await fleetctl(base, nora, "stop", "H2OmniX Alpha")).exit_code == 0

        listed = await fleetctl(base, nora, "commands", "H2OmniX Alpha")
        assert listed.exit_code == 0, listed.output
        row = next(line for line in listed.stdout.splitlines() if go_id in line)
        assert "superseded" in row and "cancelled" not in row  # a stop took its place
        as_json = json.loads((await fleetctl(base, nora, "commands", iid, "--json")).stdout)
        assert {c["status"] for c in as_json["commands"] if c["type"] != "stop"} == {"cancelled"}

        assert (await fleetctl(base, nora, "release", "H2OmniX Alpha")).exit_code == 0
        assert (await fleetctl(base, ADMIN_TOKEN, "grant", vid, "nora")).exit_code == 0
        assert (await fleetctl(base, ADMIN_TOKEN, "revoke", "H2OmniX Alpha")).exit_code == 0

        unknown = await fleetctl(base, nora, "goto", "Zulu", "43.9", "15.4")
        assert unknown.exit_code == 1 and "404 not_found" in unknown.stderr
        assert "'Zulu'" in unknown.stderr and unknown.stdout == ""
        hidden = await fleetctl(base, nora, "stop", "Twin")  # not hers: not found
        assert hidden.exit_code == 1 and "not_found" in hidden.stderr
        ambiguous = await fleetctl(base, ADMIN_TOKEN, "stop", "TWIN")
        assert ambiguous.exit_code == 2 and "ambiguous_name" in ambiguous.stderr
        assert twin_a in ambiguous.stderr and twin_b in ambiguous.stderr
        exact = await fleetctl(base, ADMIN_TOKEN, "stop", "Twin", "--json")
        assert exact.exit_code == 0  # the exact name is one vehicle


async def test_the_commands_table_reads_whole_at_80_columns(
    make_settings: Callable[..., Settings], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``COLUMNS=80 fleetctl commands``: each command on a row with its type, status, who
    issued it, when and its id whole, and its last detail wrapped under it, never cut to
    ``ad…`` (the issuer and the detail were, beside a type column padded to 14)."""
    async with served_vehicle(make_settings()) as (base, c, vid, vh, iid):
        _, op = await make_user(c, "operator", vehicles=[vid], username="ana")
        ana = op["Authorization"].removeprefix("Bearer ")
        assert (await fleetctl(base, ADMIN_TOKEN, "grant", vid, "ana")).exit_code == 0
        went = json.loads(
            (await fleetctl(base, ana, "goto", vid, "43.95", "15.45", "--json")).stdout
        )
        go_id = went["commands"][0]["command_id"]
        r = await c.get("/upper/get_control", headers=vh, params={"instance_id": iid})
        assert r.status_code == 200, r.text
        arrived = "arrived within 2.0 m of the target after 41 s"
        ack = {"command_id": go_id, "status": "done", "detail": arrived}
        r = await c.post("/upper/update_fbmessage", headers=vh,
                         json={"instance_id": iid, "acks": [ack]})  # fmt: skip
        assert r.status_code == 200, r.text
        held = json.loads((await fleetctl(base, ana, "station", vid, "--json")).stdout)
        station_id = held["commands"][0]["command_id"]
        stopped = json.loads((await fleetctl(base, ADMIN_TOKEN, "stop", vid, "--json")).stdout)
        stop_id = stopped["commands"][0]["command_id"]

        monkeypatch.setenv("COLUMNS", "80")
        narrow = await fleetctl(base, ana, "commands", vid)
        assert narrow.exit_code == 0, narrow.output
        lines = narrow.stdout.splitlines()
        assert "…" not in narrow.stdout and max(map(len, lines)) <= 80, narrow.stdout
        rows = {cid: next(line for line in lines if cid in line)
                for cid in (go_id, station_id, stop_id)}  # fmt: skip
        clock = r"\d\d:\d\d(:\d\d)?"  # HH:MM:SS today (MM-DD HH:MM past midnight UTC)
        assert re.search(rf"go_to +done +ana +{clock}", rows[go_id]), rows[go_id]
        assert re.search(
            rf"keep_station +superseded +ana +{clock} .* by a stop *$", rows[station_id]
        )
        assert re.search(rf"stop +\w+ +admin +{clock}", rows[stop_id]), rows[stop_id]
        assert all(word in narrow.stdout for word in arrived.split())  # wrapped, whole

        monkeypatch.setenv("COLUMNS", "120")
        wide = await fleetctl(base, ana, "commands", vid)
        row = next(line for line in wide.stdout.splitlines() if go_id in line)
        assert arrived in row and max(map(len, wide.stdout.splitlines())) <= 120


async def test_control_commands_name_the_vehicle_not_its_instance(
    make_settings: Callable[..., Settings], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``requests`` has the vehicle's id and name; ``request``, ``grant``, ``deny``,
    ``revoke`` and ``release`` say which vehicle (they named its instance, ``i-...``,
    alone: a field manager could not tell the boats apart)."""
    async with served_vehicle(make_settings(), name="H2OmniX Alpha") as (base, c, vid, _, iid):
        _, op = await make_user(c, "operator", vehicles=[vid], username="nora")
        nora = op["Authorization"].removeprefix("Bearer ")
        boat = f"H2OmniX Alpha ({vid})"

        asked = await fleetctl(base, nora, "request", "H2OmniX Alpha")
        assert asked.exit_code == 0 and f"control of {boat} requested" in asked.stdout
        monkeypatch.setenv("COLUMNS", "80")
        pending = await fleetctl(base, ADMIN_TOKEN, "requests")
        assert pending.exit_code == 0, pending.output
        row = next(line for line in pending.stdout.splitlines() if "nora" in line)
        assert vid in row and "H2OmniX Alpha" in row and iid in row, pending.stdout
        assert max(map(len, pending.stdout.splitlines())) <= 80, pending.stdout

        denied = await fleetctl(base, ADMIN_TOKEN, "deny", "H2OmniX Alpha", "nora")
        assert denied.stdout == f"nora's request for control of {boat} declined\n"
        granted = await fleetctl(base, ADMIN_TOKEN, "grant", iid, "nora")  # its instance
        assert granted.stdout.startswith(f"nora holds {boat} until "), granted.output
        released = await fleetctl(base, nora, "release", vid)
        assert released.stdout == f"control of {boat} released\n", released.output
        assert (await fleetctl(base, ADMIN_TOKEN, "grant", vid, "nora")).exit_code == 0
        revoked = await fleetctl(base, ADMIN_TOKEN, "revoke", "h2omnix alpha")
        assert revoked.stdout == f"control of {boat} revoked\n", revoked.output
        nobody = await fleetctl(base, ADMIN_TOKEN, "revoke", vid)
        assert nobody.stdout == f"nobody held {boat}\n", nobody.output


async def test_cancel_of_a_command_already_final_says_it_was_not_cancelled(
    make_settings: Callable[..., Settings],
) -> None:
    """The server answers a cancel of a final command with the command (``docs/api.md``);
    ``fleetctl cancel`` printed ``c-... done`` as it prints ``c-... cancelled``, and a stop
    that had already ended read as one cancelled."""
    async with served_vehicle(make_settings()) as (base, c, _, vh, iid):
        stopped = await fleetctl(base, ADMIN_TOKEN, "stop", iid, "--json")
        [command] = json.loads(stopped.stdout)["commands"]
        r = await c.get("/upper/get_control", headers=vh, params={"instance_id": iid})
        assert r.status_code == 200, r.text
        ack = {"command_id": command["command_id"], "status": "done"}
        r = await c.post("/upper/update_fbmessage", headers=vh,
                         json={"instance_id": iid, "acks": [ack]})  # fmt: skip
        assert r.status_code == 200, r.text

        late = await fleetctl(base, ADMIN_TOKEN, "cancel", command["command_id"])
        assert late.exit_code == 0, late.output  # answered, not refused
        assert late.stdout.split() == [command["command_id"], "done:", "final", "already,",
                                       "not", "cancelled"]  # fmt: skip
        as_json = await fleetctl(base, ADMIN_TOKEN, "cancel", command["command_id"], "--json")
        assert json.loads(as_json.stdout)["status"] == "done"  # the answer, as it was
