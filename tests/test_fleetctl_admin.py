"""``fleetctl vehicles``, ``gateways`` and ``users`` against a real server: registering, the
token printed alone on stdout, issuing a new one and revoking them, disabling a user."""

from __future__ import annotations

import asyncio
import json
import os
import re
import sys
from collections.abc import Callable

import httpx
import pytest

from server.settings import Settings
from tests.factories import ADMIN_TOKEN, bearer, make_user, make_vehicle
from tests.fleetctl_run import fleetctl, token_of
from tests.live import serve

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


async def _starts(c: httpx.AsyncClient, vehicle_id: str, token: str) -> int:
    """The status ``start_instance`` answers a vehicle (or gateway) token."""
    body = {"vehicle_id": vehicle_id, "name": "", "vehicle_type": "usv", "capabilities": []}
    return (await c.post("/upper/start_instance", headers=bearer(token), json=body)).status_code


async def test_vehicles_are_registered_and_their_tokens_issued_and_revoked(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        added = await fleetctl(base, ADMIN_TOKEN, "vehicles", "add", "cli-usv", "--name", "Delta")
        assert added.exit_code == 0, added.output
        first = added.stdout.strip()
        assert added.stdout == first + "\n" and first.startswith("fct_")  # the token alone
        assert "shown this once" in added.stderr and "FLEET_AGENT_TOKEN" in added.stderr
        assert await _starts(c, "cli-usv", first) == 200

        table = await fleetctl(base, ADMIN_TOKEN, "vehicles")  # no subcommand: the list
        assert table.exit_code == 0 and "cli-usv" in table.stdout and "Delta" in table.stdout
        listed = await fleetctl(base, ADMIN_TOKEN, "vehicles", "list", "--json")
        [view] = json.loads(listed.stdout)["vehicles"]
        assert (view["vehicle_id"], view["presence"]) == ("cli-usv", "online")
        assert json.loads((await fleetctl(base, ADMIN_TOKEN, "vehicles", "--json")).stdout) == {
            "vehicles": [view]
        }

        issued = await fleetctl(base, ADMIN_TOKEN, "vehicles", "token", "Delta")  # by name
        assert issued.exit_code == 0, issued.output
        second = issued.stdout.strip()
        assert "former ones are revoked" in issued.stderr
        assert await _starts(c, "cli-usv", first) == 401
        assert await _starts(c, "cli-usv", second) == 200

        revoked = await fleetctl(base, ADMIN_TOKEN, "vehicles", "revoke", "delta")
        assert revoked.exit_code == 0 and "every token of vehicle cli-usv revoked" in revoked.stdout
        assert await _starts(c, "cli-usv", second) == 401
        third = await fleetctl(base, ADMIN_TOKEN, "vehicles", "token", "cli-usv", "--json")
        answer = json.loads(third.stdout)
        assert answer["vehicle_id"] == "cli-usv" and await _starts(c, "cli-usv", answer["token"])

        taken = await fleetctl(base, ADMIN_TOKEN, "vehicles", "add", "cli-usv")
        assert taken.exit_code == 1 and "409" in taken.stderr and taken.stdout == ""
        bad_id = await fleetctl(base, ADMIN_TOKEN, "vehicles", "add", "Not An Id")
        assert bad_id.exit_code == 2 and "VEHICLE_ID is 1 to 64 characters" in bad_id.stderr
        nobody = await fleetctl(base, ADMIN_TOKEN, "vehicles", "token", "Zulu")
        assert nobody.exit_code == 1 and "'Zulu'" in nobody.stderr
        _, op = await make_user(c, "operator", vehicles=["cli-usv"])
        refused = await fleetctl(base, token_of(op), "vehicles", "add", "cli-usv-2")
        assert refused.exit_code == 1 and "403 forbidden" in refused.stderr
        assert (await fleetctl(base, token_of(op), "vehicles")).exit_code == 0  # lists its own
        no_token = await fleetctl(base, "", "vehicles")
        assert no_token.exit_code == 2


async def test_gateways_are_registered_and_their_tokens_issued_and_revoked(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, _ = await make_vehicle(c)
        added = await fleetctl(base, ADMIN_TOKEN, "gateways", "add", "cli-gw", "--vehicle", vid)
        assert added.exit_code == 0, added.output
        first = added.stdout.strip()
        assert f"registered for {vid}" in added.stderr
        assert await _starts(c, vid, first) == 200

        issued = await fleetctl(base, ADMIN_TOKEN, "gateways", "token", "cli-gw", "--json")
        answer = json.loads(issued.stdout)
        assert answer["vehicles"] == [vid]
        assert await _starts(c, vid, first) == 401
        assert await _starts(c, vid, answer["token"]) == 200
        listed = await fleetctl(base, ADMIN_TOKEN, "gateways", "--json")
        assert json.loads(listed.stdout)["gateways"] == [
            {"gateway_id": "cli-gw", "vehicles": [vid], "active_tokens": 1,
             "created_at": json.loads(listed.stdout)["gateways"][0]["created_at"]}
        ]  # fmt: skip
        revoked = await fleetctl(base, ADMIN_TOKEN, "gateways", "revoke", "cli-gw")
        assert revoked.exit_code == 0 and "every token of gateway cli-gw" in revoked.stdout
        assert await _starts(c, vid, answer["token"]) == 401
        table = await fleetctl(base, ADMIN_TOKEN, "gateways", "list")
        assert table.exit_code == 0 and "cli-gw" in table.stdout and "revoked" in table.stdout
        assert vid in table.stdout
        _, op = await make_user(c, "operator", vehicles=[vid])
        refused = await fleetctl(base, token_of(op), "gateways")
        assert refused.exit_code == 1 and "403 forbidden" in refused.stderr

        unknown = await fleetctl(base, ADMIN_TOKEN, "gateways", "token", "no-gw")
        assert unknown.exit_code == 1 and "404" in unknown.stderr
        none = await fleetctl(base, ADMIN_TOKEN, "gateways", "add", "gw-2", "--vehicle", "Zulu")
        assert none.exit_code == 1 and "'Zulu'" in none.stderr


async def test_users_are_added_changed_disabled_and_their_tokens_issued_and_revoked(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, _ = await make_vehicle(c)
        added = await fleetctl(
            base, ADMIN_TOKEN, "users", "add", "ana", "--role", "operator", "--vehicle", vid
        )
        assert added.exit_code == 0, added.output
        ana = added.stdout.strip()
        assert f"user ana (operator; {vid}) created" in added.stderr
        seen = await fleetctl(base, ana, "vehicles", "--json")
        assert [v["vehicle_id"] for v in json.loads(seen.stdout)["vehicles"]] == [vid]

        table = await fleetctl(base, ADMIN_TOKEN, "users")  # no subcommand: the list
        row = next(line for line in table.stdout.splitlines() if "ana" in line)
        assert "operator" in row and vid in row and "active" in row
        assert (await fleetctl(base, ADMIN_TOKEN, "users", "list")).stdout == table.stdout

        demoted = await fleetctl(base, ADMIN_TOKEN, "users", "set", "ana", "--role", "viewer")
        assert demoted.exit_code == 0 and demoted.stdout.startswith("ana: viewer, active")
        emptied = await fleetctl(
            base, ADMIN_TOKEN, "users", "set", "ana", "--no-vehicles", "--json"
        )
        assert json.loads(emptied.stdout)["vehicles"] == []
        given = await fleetctl(base, ADMIN_TOKEN, "users", "set", "ana", "--vehicle", vid.upper())
        assert given.exit_code == 0 and vid in given.stdout  # the vehicle's name (its id, upper)

        disabled = await fleetctl(base, ADMIN_TOKEN, "users", "disable", "ana")
        assert disabled.exit_code == 0 and "disabled" in disabled.stdout
        shut = await fleetctl(base, ana, "vehicles")
        assert shut.exit_code == 1 and "401" in shut.stderr
        assert (await fleetctl(base, ADMIN_TOKEN, "users", "enable", "ana")).exit_code == 0
        assert (await fleetctl(base, ana, "vehicles")).exit_code == 0

        issued = await fleetctl(base, ADMIN_TOKEN, "users", "token", "ana")
        fresh = issued.stdout.strip()
        assert (await fleetctl(base, ana, "vehicles")).exit_code == 1
        assert (await fleetctl(base, fresh, "vehicles")).exit_code == 0
        revoked = await fleetctl(base, ADMIN_TOKEN, "users", "revoke", "ana", "--json")
        assert json.loads(revoked.stdout) == {"ok": True}
        assert (await fleetctl(base, fresh, "vehicles")).exit_code == 1

        with_password = await fleetctl(
            base,
            ADMIN_TOKEN,
            "users",
            "add",
            "bo",
            "--ask-password",
            input="s3cret-harbour\ns3cret-harbour\n",
        )
        assert with_password.exit_code == 0, with_password.output
        login = await c.post("/auth/token", json={"username": "bo", "password": "s3cret-harbour"})
        assert login.status_code == 200 and login.json()["token_type"] == "bearer"

        bad_role = await fleetctl(base, ADMIN_TOKEN, "users", "add", "cy", "--role", "captain")
        assert bad_role.exit_code == 2 and "viewer, operator, manager, admin" in bad_role.stderr
        nothing = await fleetctl(base, ADMIN_TOKEN, "users", "set", "bo")
        assert nothing.exit_code == 2 and "nothing to change" in nothing.stderr
        unknown = await fleetctl(base, ADMIN_TOKEN, "users", "disable", "nobody")
        assert unknown.exit_code == 1 and "404" in unknown.stderr
        not_admin = await fleetctl(base, fresh, "users")
        assert not_admin.exit_code == 1


async def test_the_users_and_gateways_tables_fit_80_columns(
    make_settings: Callable[..., Settings], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Their ``created`` whole, to the second (``2026-11-27 09:29:51``), not cut to
    ``2026-11-27T09:29:51.82…``; the vehicles wrap."""
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        first, _ = await make_vehicle(c, "demo-usv-1")
        second, _ = await make_vehicle(c, "demo-usv-2")
        await make_user(c, "operator", [first, second], username="ana")
        await make_user(c, "manager", [first], username="fm-north")
        added = await fleetctl(
            base, ADMIN_TOKEN, "gateways", "add", "gw-1", "-v", first, "-v", second
        )
        assert added.exit_code == 0, added.output

        monkeypatch.setenv("COLUMNS", "80")
        for listing, names in (("users", ["admin", "ana", "fm-north"]), ("gateways", ["gw-1"])):
            table = await fleetctl(base, ADMIN_TOKEN, listing)
            assert table.exit_code == 0, table.output
            lines = table.stdout.splitlines()
            assert "…" not in table.stdout and max(map(len, lines)) <= 80, table.stdout
            for name in names:
                row = next(line for line in lines if f" {name} " in line)
                assert re.search(r" \d{4}-\d\d-\d\d \d\d:\d\d:\d\d ", row), row


async def test_the_password_prompts_go_to_stderr_and_the_token_alone_to_stdout(
    make_settings: Callable[..., Settings],
) -> None:
    """``T=$(fleetctl users add ben --ask-password)``: the prompts are on stderr, so the
    shell keeps the token alone (they went to stdout: T held "password:Repeat for
    confirmation:fct_..."). A process of its own, with no terminal to ask on: the
    password is read from stdin, as getpass does then."""
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        env = {**os.environ, "FLEET_SERVER": base, "FLEET_TOKEN": ADMIN_TOKEN}
        fleetctl_process = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "remote_client", "users", "add", "ben", "--ask-password",
            env=env, stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE, start_new_session=True,  # no controlling terminal
        )  # fmt: skip
        async with asyncio.timeout(30):
            stdout, stderr = await fleetctl_process.communicate(b"harbour-gate\nharbour-gate\n")
        assert fleetctl_process.returncode == 0, stderr.decode()
        token = stdout.decode().strip()
        assert stdout.decode() == token + "\n" and token.startswith("fct_"), stdout
        assert "password" in stderr.decode() and "Repeat for confirmation" in stderr.decode()
        login = await c.post("/auth/token", json={"username": "ben", "password": "harbour-gate"})
        assert login.status_code == 200, login.text
        assert (await c.get("/api/me", headers=bearer(token))).json()["username"] == "ben"


async def test_a_vehicles_name_and_type_are_put_right_by_name_or_id(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, _ = await make_vehicle(c, "cli-auv", vehicle_type="usv")  # named CLI-AUV
        done = await fleetctl(base, ADMIN_TOKEN, "vehicles", "set", "CLI-AUV", "--type", "auv")
        assert done.exit_code == 0, done.output
        assert "vehicle cli-auv: CLI-AUV (auv)" in done.stdout
        done = await fleetctl(
            base, ADMIN_TOKEN, "vehicles", "set", vid, "--name", "Deep One", "--json"
        )
        assert done.exit_code == 0, done.output
        answer = json.loads(done.stdout)
        assert (answer["name"], answer["vehicle_type"]) == ("Deep One", "auv")
        view = (await c.get(f"/api/vehicles/{vid}", headers=bearer(ADMIN_TOKEN))).json()
        assert (view["name"], view["vehicle_type"]) == ("Deep One", "auv")

        nothing = await fleetctl(base, ADMIN_TOKEN, "vehicles", "set", vid)
        assert nothing.exit_code != 0 and "give --name or --type" in nothing.output
        _, operator = await make_user(c, "operator", [vid])
        refused = await fleetctl(
            base, operator["Authorization"][7:], "vehicles", "set", vid, "--name", "X"
        )
        assert refused.exit_code != 0 and "admin" in refused.output
        bad = await fleetctl(base, ADMIN_TOKEN, "vehicles", "set", vid, "--type", "")
        assert bad.exit_code != 0 and "vehicle_type" in bad.output


async def test_a_user_with_a_password_logs_in_works_with_the_session_and_logs_out(
    make_settings: Callable[..., Settings],
) -> None:
    """``fleetctl login`` (the password asked, or from stdin): the session token alone on
    stdout, which works as FLEET_TOKEN until ``fleetctl logout``; a wrong password is
    refused (exit 1, 401) and prints no token; an API token outlives a logout."""
    async with serve(make_settings()) as base:
        made = await fleetctl(
            base,
            ADMIN_TOKEN,
            "users",
            "add",
            "ben",
            "--role",
            "operator",
            "--ask-password",
            input="s3cret-pass\ns3cret-pass\n",
        )
        assert made.exit_code == 0, made.output
        api_token = made.stdout.strip()

        wrong = await fleetctl(base, "", "login", "ben", input="nope-nope\n")
        # (the test runner echoes the hidden input's newline on stdout; a terminal does not)
        assert wrong.exit_code == 1 and wrong.stdout.strip() == "", wrong.output
        assert "401" in wrong.stderr

        asked = await fleetctl(base, "", "login", "ben", input="s3cret-pass\n")
        assert asked.exit_code == 0, asked.output
        session = asked.stdout.strip()
        assert asked.stdout.split() == [session] and session != api_token  # the token alone
        assert "logged in as ben for 12 h" in asked.stderr
        piped = await fleetctl(
            base, "", "login", "ben", "--password-stdin", "--json", input="s3cret-pass\n"
        )
        assert json.loads(piped.stdout)["expires_in"] == 12 * 3600, piped.output

        listed = await fleetctl(base, session, "vehicles")
        assert listed.exit_code == 0, listed.output
        ended = await fleetctl(base, session, "logout")
        assert ended.exit_code == 0 and "session ended" in ended.stdout, ended.output
        after = await fleetctl(base, session, "vehicles")
        assert after.exit_code == 1 and "401" in after.stderr, after.output

        kept = await fleetctl(base, api_token, "logout")
        assert kept.exit_code == 0 and "stays valid" in kept.stdout, kept.output
        assert (await fleetctl(base, api_token, "vehicles")).exit_code == 0
