"""``examples/sdk_tour.py``, the SDK walk-through of docs/sdk.md, run as a user runs it
against a real server: every step it prints, a refusal included."""

from __future__ import annotations

import asyncio
import os
import sys
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest

from server.settings import Settings
from tests.factories import ADMIN, ADMIN_TOKEN, make_user, sample
from tests.fleetctl_run import served_vehicle

TOUR = Path(__file__).resolve().parents[1] / "examples" / "sdk_tour.py"

pytestmark = pytest.mark.usefixtures("store_backend")


async def test_the_sdk_tour_runs_as_written(make_settings: Callable[..., Settings]) -> None:
    async with served_vehicle(make_settings(), name="Tour Boat") as (base, c, vid, vh, iid):
        now = datetime.now(UTC)  # within the tour's "last hour"
        first = {"instance_id": iid, "params": {"mode": "survey"}, "samples": [sample(1, now)]}
        assert (await c.post("/upper/update_param", headers=vh, json=first)).is_success
        _, op = await make_user(c, "operator", vehicles=[vid], username="tess")
        seq = 1

        async def run_tour(token: str) -> str:
            nonlocal seq
            env = {**os.environ, "FLEET_SERVER": base, "FLEET_TOKEN": token}
            tour = await asyncio.create_subprocess_exec(
                sys.executable, str(TOUR), "Tour Boat",
                env=env, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
            )  # fmt: skip
            async with asyncio.timeout(60):
                while tour.returncode is None:  # the boat moves on: its topic changes
                    seq += 1
                    later = sample(seq, now + timedelta(seconds=seq), lat=43.94 + seq * 1e-5)
                    body = {"instance_id": iid, "samples": [later]}
                    await c.post("/upper/update_param", headers=vh, json=body)
                    try:
                        await asyncio.wait_for(tour.wait(), 0.3)
                    except TimeoutError:
                        pass
                out, err = await tour.communicate()
            assert tour.returncode == 0, err.decode()
            return out.decode()

        text = await run_tour(op["Authorization"].removeprefix("Bearer "))
        # the token that holds control (the README's grant to admin): the go_to goes
        grant = {"instance_id": iid, "user": "admin", "duration_s": 600}
        assert (await c.post("/client/grant_control", headers=ADMIN, json=grant)).is_success
        held = await run_tour(ADMIN_TOKEN)
    assert "go_to: queued" in held and "refused" not in held, held
    assert f"{vid}" in text and "Tour Boat" in text and "online" in text
    assert "params: {'mode': 'survey'}" in text
    assert "events in the last hour: [" in text and "'instance'" in text
    assert "samples: " in text and "from seq 1" in text
    assert "refused: 409 control_not_held" in text  # nobody granted control yet
    assert "event snapshot seq" in text and "event change seq" in text
