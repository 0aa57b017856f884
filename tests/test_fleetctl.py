"""``fleetctl`` against a real server: tables for people, JSON for scripts, errors on stderr."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Callable

import httpx
from typer.testing import CliRunner, Result

from remote_client.cli import app
from server.settings import Settings
from tests.factories import ADMIN_TOKEN, make_user, make_vehicle, start_instance
from tests.live import serve

runner = CliRunner()


async def _fleetctl(base: str, token: str, *args: str) -> Result:
    env = {"FLEET_SERVER": base, "FLEET_TOKEN": token}
    return await asyncio.to_thread(runner.invoke, app, list(args), env=env)


async def test_an_operator_lists_is_refused_then_granted_and_commands(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, vh = await make_vehicle(c)
        iid = (await start_instance(c, vid, vh))["instance_id"]
        _, op = await make_user(c, "operator", vehicles=[vid], username="olga")
        op_token = op["Authorization"].removeprefix("Bearer ")

        listed = await _fleetctl(base, op_token, "vehicles", "--json")
        assert listed.exit_code == 0, listed.output
        assert [v["instance_id"] for v in json.loads(listed.stdout)["vehicles"]] == [iid]
        table = await _fleetctl(base, op_token, "vehicles")
        assert vid in table.stdout and "online" in table.stdout

        refused = await _fleetctl(base, op_token, "goto", iid, "43.95", "15.45", "--json")
        assert refused.exit_code == 1
        assert refused.stdout == ""  # a script reading --json output sees no error text
        assert "409 control_not_held" in refused.stderr and iid in refused.stderr

        granted = await _fleetctl(base, ADMIN_TOKEN, "grant", iid, "olga", "--json")
        assert granted.exit_code == 0, granted.output
        assert json.loads(granted.stdout)["holder"] == "olga"

        sent = await _fleetctl(base, op_token, "goto", iid, "43.95", "15.45", "--json")
        assert sent.exit_code == 0, sent.output
        command = json.loads(sent.stdout)["commands"][0]
        assert command["instance_id"] == iid and command["status"] == "queued"

        bad = await _fleetctl(base, op_token, "goto", iid, "95", "15.45")
        assert bad.exit_code == 1 and "422 invalid" in bad.stderr
        assert "command.args.lat" in bad.stderr  # each detail on its own line

        everyone = await _fleetctl(base, ADMIN_TOKEN, "stop", "--json")
        assert everyone.exit_code == 0, everyone.output
        assert [s["instance_id"] for s in json.loads(everyone.stdout)["commands"]] == [iid]


async def test_an_unreachable_server_is_exit_code_3(make_settings: Callable[..., Settings]) -> None:
    async with serve(make_settings()) as base:
        pass  # stopped: its port is closed now
    gone = await _fleetctl(base, ADMIN_TOKEN, "vehicles")
    assert gone.exit_code == 3 and "cannot reach" in gone.stderr and gone.stdout == ""
