"""What ``fleetctl`` prints that a vehicle, an operator or an admin wrote reaches the
terminal escaped (``docs/limits.md``): a parameter's name and value, a zone's and an
obstacle's name (as an older server stored them), a command's detail, an event's
data, an alarm. No escape sequence, control character or character that reorders a
line is printed raw by any command, on stdout or stderr, and nothing is read as rich's
markup."""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from datetime import UTC, datetime

import httpx
import pytest
from click.testing import Result

from fleet_protocol import CreateObstacle, CreateZone
from server.app import create_app
from server.settings import Settings
from tests.factories import ADMIN_TOKEN, make_vehicle, sample, start_instance
from tests.fleetctl_run import fleetctl
from tests.live import call, connect, recv_until, serve

pytestmark = pytest.mark.usefixtures("store_backend")

#: A terminal would set its title and clear the screen.
ATTACK = "\x1b]0;pwned\x07\x1b[2Jk"
ATTACK_SHOWN = "\\x1b]0;pwned\\x07\\x1b[2Jk"
#: A terminal would show "abcfed".
BIDI = "abc\u202edef"
BIDI_SHOWN = "abc\\u202edef"
#: rich would fail the whole table on it, taken for a closing tag.
MARKUP = "[/x] :smile:"
#: What must never reach a terminal raw: control characters but the line break, and the
#: characters that reorder a line.
RAW = re.compile("[\x00-\x09\x0b-\x1f\x7f-\x9f\u202a-\u202e\u2066-\u2069]")

RING = [[15.40, 43.90], [15.41, 43.90], [15.41, 43.91], [15.40, 43.91], [15.40, 43.90]]
SQUARE = {"type": "Polygon", "coordinates": [RING]}


def _printed(result: Result, *shown: str) -> str:
    """``result``'s stdout, after checking that it and stderr hold nothing raw and that
    stdout shows each of ``shown``."""
    assert result.exit_code == 0, result.output
    for stream in (result.stdout, result.stderr):
        assert RAW.search(stream) is None, stream
    for text in shown:
        assert text in result.stdout, result.stdout
    return result.stdout


async def test_every_listing_shows_what_others_wrote_escaped(
    make_settings: Callable[..., Settings], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("COLUMNS", "400")  # a table's cells on one line each
    app = create_app(make_settings())
    async with serve(Settings(), app=app) as base, httpx.AsyncClient(base_url=base) as c:
        vid, vh = await make_vehicle(c)
        params = {ATTACK: "v", "bidi": BIDI, "markup": MARKUP}
        iid = (await start_instance(c, vid, vh, params=params))["instance_id"]
        # What an older server let an admin name a zone and an obstacle, as it stored it.
        services = app.state.services
        zone = CreateZone(name="z", kind="no_go", polygon=SQUARE, vehicles=[vid])
        zone_id = (
            await services.zones.create(zone.model_copy(update={"name": ATTACK + BIDI}), "admin")
        )["zone_id"]
        rock = CreateObstacle(name="o", polygon=SQUARE).model_copy(update={"name": BIDI + MARKUP})
        await services.obstacles.create(rock)
        async with await connect(base, "/ws/client", ADMIN_TOKEN) as ws:
            await call(ws, "subscribe", "s", topics=["fleet"])
            inside = sample(1, datetime.now(UTC), lat=43.905, lon=15.405)
            r = await c.post("/upper/update_param", headers=vh,
                             json={"instance_id": iid, "samples": [inside]})  # fmt: skip
            assert r.status_code == 200, r.text
            await recv_until(  # the breach is taken in the background
                ws,
                lambda f: (
                    f["op"] == "event" and any(v.get("alarms") for v in f["data"]["vehicles"])
                ),
            )

        stopped = await fleetctl(base, ADMIN_TOKEN, "stop", vid, "--json")
        [command] = json.loads(stopped.stdout)["commands"]
        r = await c.get("/upper/get_control", headers=vh, params={"instance_id": iid})
        assert r.status_code == 200, r.text
        ack = {"command_id": command["command_id"], "status": "failed", "detail": ATTACK + BIDI}
        r = await c.post("/upper/update_fbmessage", headers=vh,
                         json={"instance_id": iid, "acks": [ack]})  # fmt: skip
        assert r.status_code == 200, r.text

        listing = await fleetctl(base, ADMIN_TOKEN, "params", vid)
        _printed(listing, ATTACK_SHOWN, BIDI_SHOWN, MARKUP)
        _printed(await fleetctl(base, ADMIN_TOKEN, "zones"), ATTACK_SHOWN + BIDI_SHOWN)
        edited = await fleetctl(base, ADMIN_TOKEN, "zones", "edit", zone_id, "--clearance", "5")
        _printed(edited, ATTACK_SHOWN + BIDI_SHOWN)
        _printed(await fleetctl(base, ADMIN_TOKEN, "obstacles"), BIDI_SHOWN + MARKUP)
        alarmed = await fleetctl(base, ADMIN_TOKEN, "vehicles")
        _printed(alarmed, f"inside no-go zone {ATTACK_SHOWN}{BIDI_SHOWN}")
        _printed(await fleetctl(base, ADMIN_TOKEN, "commands", vid), ATTACK_SHOWN + BIDI_SHOWN)
        logged = await fleetctl(base, ADMIN_TOKEN, "events", vid)
        _printed(logged, "\\u001b]0;pwned\\u0007\\u001b[2Jk" + BIDI_SHOWN)  # JSON, escaped
        _printed(await fleetctl(base, ADMIN_TOKEN, "audit", "show", vid))

        fleet = await fleetctl(base, ADMIN_TOKEN, "watch", "--count", "1")
        _printed(fleet, f"inside no-go zone {ATTACK_SHOWN}{BIDI_SHOWN}")
        topic = f"vehicle/{vid}/commands"
        commands = await fleetctl(base, ADMIN_TOKEN, "watch", topic, "--count", "1")
        _printed(commands, ATTACK_SHOWN + BIDI_SHOWN)

        removed = await fleetctl(base, ADMIN_TOKEN, "zones", "remove", zone_id)
        _printed(removed, ATTACK_SHOWN + BIDI_SHOWN)
        refused = await fleetctl(base, ADMIN_TOKEN, "zones", "remove", ATTACK)
        assert refused.exit_code == 1 and RAW.search(refused.stderr) is None, refused.stderr
        assert ATTACK_SHOWN in refused.stderr
