"""``fleetctl publish`` (and the SDK's ``publish``): one message on a topic, to whoever
subscribes to it; refusals as the server gives them, bad arguments before anything."""

from __future__ import annotations

import json
from collections.abc import Callable

import httpx
import pytest

from server.settings import Settings
from tests.factories import make_user, make_vehicle
from tests.fleetctl_run import fleetctl, token_of
from tests.live import call, connect, recv_until, serve

pytestmark = pytest.mark.usefixtures("store_backend")


async def test_a_message_published_from_the_command_line_reaches_its_subscriber(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, vh = await make_vehicle(c)
        _, ana = await make_user(c, "operator", [vid], username="ana")
        plan = f"user/ana/plan/{vid}"
        async with await connect(base, "/ws/vehicle", token_of(vh)) as unit:
            assert (await call(unit, "subscribe", "s", topics=[plan]))["ok"] is True
            sent = await fleetctl(base, token_of(ana), "publish", plan, '{"leg": 2, "m": 12.5}')
            assert sent.exit_code == 0, sent.output
            assert sent.stdout == f"published on {plan}\n"
            got = await recv_until(unit, lambda f: f["op"] == "event" and f["topic"] == plan)
            assert got["data"] == {"leg": 2, "m": 12.5} and got["source"] == "user:ana"

        scripted = await fleetctl(base, token_of(ana), "publish", plan, "42", "--json")
        assert json.loads(scripted.stdout) == {"topic": plan, "published": True}
        theirs = await fleetctl(base, token_of(ana), "publish", f"vehicle/{vid}/x", "{}")
        assert theirs.exit_code == 1 and "403 forbidden" in theirs.stderr  # not its namespace
        for data, said in (("{not json", "DATA is JSON"), ("NaN", "NaN is not a JSON number")):
            bad = await fleetctl(base, token_of(ana), "publish", plan, data)
            assert bad.exit_code == 2 and said in bad.stderr, bad.output
        malformed = await fleetctl(base, token_of(ana), "publish", "User/Ana", "{}")
        assert malformed.exit_code == 2 and "not a topic" in malformed.stderr
