"""One ``fleetctl`` mission for several vehicles: ``goto`` and ``path`` as ``station`` and
``stop`` take them, each vehicle named by id or by name."""

from __future__ import annotations

import json
from collections.abc import Callable

import httpx
import pytest

from server.settings import Settings
from tests.factories import ADMIN, ADMIN_TOKEN, make_user, make_vehicle, start_instance
from tests.fleetctl_run import fleetctl
from tests.live import serve

pytestmark = pytest.mark.usefixtures("store_backend")


async def test_goto_and_path_send_one_mission_to_several_vehicles(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        (a, ah), (b, bh) = await make_vehicle(c), await make_vehicle(c)
        ia = (await start_instance(c, a, ah))["instance_id"]
        ib = (await start_instance(c, b, bh))["instance_id"]
        _, op = await make_user(c, "operator", vehicles=[a, b], username="mara")
        op_token = op["Authorization"].removeprefix("Bearer ")
        for iid in (ia, ib):
            assert (await fleetctl(base, ADMIN_TOKEN, "grant", iid, "mara")).exit_code == 0

        # The second boat by its name (make_vehicle names it in capitals).
        sent = await fleetctl(base, op_token, "goto", ia, b.upper(), "43.95", "-15.45", "--json")
        assert sent.exit_code == 0, sent.output
        answer = json.loads(sent.stdout)
        assert {cmd["instance_id"] for cmd in answer["commands"]} == {ia, ib}
        assert any("2 vehicles sent to one point" in w for w in answer["warnings"])
        for cmd in answer["commands"]:
            stored = (await c.get(f"/api/commands/{cmd['command_id']}", headers=ADMIN)).json()
            assert stored["type"] == "go_to"
            assert (stored["args"]["lat"], stored["args"]["lon"]) == (43.95, -15.45)

        printed = await fleetctl(base, op_token, "path", ia, ib, "43.941,15.441", "43.942,15.45")
        assert printed.exit_code == 0, printed.output
        assert ia in printed.stdout and ib in printed.stdout  # a line per vehicle
        listed = await c.get("/client/get_fbmessage", headers=op, params={"instance_id": ib})
        paths = [cmd for cmd in listed.json()["commands"] if cmd["type"] == "follow_path"]
        assert [p["args"]["waypoints"] for p in paths] == [
            [{"lat": 43.941, "lon": 15.441}, {"lat": 43.942, "lon": 15.45}]
        ]

        one_unheld = await fleetctl(base, ADMIN_TOKEN, "goto", ia, ib, "43.95", "15.45")
        assert one_unheld.exit_code == 1 and "control_not_held" in one_unheld.stderr


async def test_a_name_that_fits_no_vehicle_sends_nothing_and_says_so(
    make_settings: Callable[..., Settings],
) -> None:
    """``stop alpha typo``: no vehicle is stopped (the names are resolved before anything
    is sent), and the refusal says so: it named the typo alone, and a team took alpha for
    stopped."""
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        a, ah = await make_vehicle(c)
        ia = (await start_instance(c, a, ah))["instance_id"]

        stopped = await fleetctl(base, ADMIN_TOKEN, "stop", a, "no-such-boat")
        assert stopped.exit_code == 1
        assert "'no-such-boat'" in stopped.stderr
        assert "nothing sent: no vehicle stopped" in stopped.stderr
        listed = await c.get("/client/get_fbmessage", headers=ADMIN, params={"instance_id": ia})
        assert listed.json()["commands"] == []  # as it said

        went = await fleetctl(base, ADMIN_TOKEN, "goto", a, "no-such-boat", "43.9", "15.4")
        assert went.exit_code == 1 and "nothing sent" in went.stderr
