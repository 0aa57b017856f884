"""``fleetctl watch`` against a real server: the current state then each change, a line
for people per event or JSON, vehicles by name, a lost link taken up again, and a quiet
end when its output is closed (``| head -1``)."""

from __future__ import annotations

import asyncio
import json
import os
import re
import sys
from asyncio.subprocess import Process
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager

import httpx
import pytest

from server.settings import Settings
from tests.factories import ADMIN_TOKEN, make_user, make_vehicle, sample, start_instance
from tests.fleetctl_run import fleetctl, served_vehicle
from tests.live import free_port, serve

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


async def test_watch_prints_the_current_state_then_changes(
    make_settings: Callable[..., Settings],
) -> None:
    async with served_vehicle(make_settings()) as (base, c, vid, vh, iid):
        seq = 1
        r = await c.post(
            "/upper/update_param", headers=vh, json={"instance_id": iid, "samples": [sample(seq)]}
        )
        assert r.status_code == 200
        topic = f"vehicle/{vid}/telemetry"
        watching = asyncio.create_task(
            fleetctl(base, ADMIN_TOKEN, "watch", topic, "--count", "2", "--json")
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

        fleet = await fleetctl(base, ADMIN_TOKEN, "watch", "--seconds", "0.5")
        assert fleet.exit_code == 0, fleet.output
        assert fleet.stdout.startswith(f"current fleet {vid} online 43.94000,15.44000")

        _, viewer = await make_user(c, "viewer", vehicles=[])
        blind = await fleetctl(
            base, viewer["Authorization"].removeprefix("Bearer "), "watch", topic, "--seconds", "5"
        )
        assert blind.exit_code == 1 and "forbidden" in blind.stderr and blind.stdout == ""
        nobody = await fleetctl(base, "fct_not-a-token-at-all-0000000000", "watch")
        assert nobody.exit_code == 1 and "refused" in nobody.stderr


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


@asynccontextmanager
async def _watched_by_head(base: str, vid: str) -> AsyncIterator[tuple[Process, bytes]]:
    """``fleetctl watch vehicle/<vid>/telemetry | head -1``: the watch, its stdout a pipe
    whose reader has read one line and gone; and that line. Killed after, if still on."""
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
        yield watcher, first
    finally:
        if watcher.returncode is None:
            watcher.kill()
            await watcher.wait()


async def test_watch_stops_quietly_when_its_output_is_closed(
    make_settings: Callable[..., Settings],
) -> None:
    """``fleetctl watch ... | head -1``: once head has gone, the next event ends the
    watch at once, exit 141 (as SIGPIPE would), no traceback, no link taken for lost."""
    async with served_vehicle(make_settings()) as (base, c, vid, vh, iid):
        seq = 1
        body = {"instance_id": iid, "samples": [sample(seq)]}
        assert (await c.post("/upper/update_param", headers=vh, json=body)).is_success
        async with _watched_by_head(base, vid) as (watcher, first):
            exited = asyncio.ensure_future(watcher.wait())
            async with asyncio.timeout(20):
                while not exited.done():  # events until it notices
                    seq += 1
                    body = {"instance_id": iid, "samples": [sample(seq)]}
                    assert (await c.post("/upper/update_param", headers=vh, json=body)).is_success
                    await asyncio.wait({exited}, timeout=0.05)
        assert watcher.stderr is not None
        stderr = (await watcher.stderr.read()).decode()
    assert first.startswith(b"current ") and vid.encode() in first
    assert watcher.returncode == 141, stderr
    assert stderr == ""  # neither "link lost" nor a traceback


async def test_watch_ends_when_its_reader_goes_though_nothing_more_comes(
    make_settings: Callable[..., Settings],
) -> None:
    """``fleetctl watch ... | head -1`` on a quiet fleet: head has gone after the first
    line and no event follows; the watch notices all the same, within seconds, and ends
    quietly with exit 141 (it used to wait for the next change, for ever if none came)."""
    async with served_vehicle(make_settings()) as (base, c, vid, vh, iid):
        body = {"instance_id": iid, "samples": [sample(1)]}
        assert (await c.post("/upper/update_param", headers=vh, json=body)).is_success
        async with _watched_by_head(base, vid) as (watcher, first):
            async with asyncio.timeout(10):  # and nothing is sent any more
                await watcher.wait()
        assert watcher.stderr is not None
        stderr = (await watcher.stderr.read()).decode()
    assert first.startswith(b"current ") and vid.encode() in first
    assert watcher.returncode == 141, stderr
    assert stderr == ""


async def test_watch_prints_a_readable_line_per_event_and_takes_names(
    make_settings: Callable[..., Settings],
) -> None:
    async with served_vehicle(make_settings(), name="Kestrel") as (base, c, vid, vh, iid):
        seq = 1
        body = {"instance_id": iid, "samples": [sample(seq, speed_mps=1.5, battery_pct=80.0)]}
        assert (await c.post("/upper/update_param", headers=vh, json=body)).is_success
        watching = asyncio.create_task(
            fleetctl(base, ADMIN_TOKEN, "watch", "vehicle/Kestrel/telemetry", "--count", "2")
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
        nothing = await fleetctl(base, ADMIN_TOKEN, "watch", "vehicle/nosuch/telemetry",
                                  "--seconds", "0.5")  # fmt: skip
        assert nothing.exit_code == 0 and "no vehicle 'nosuch'" in nothing.stderr
        # an operator sees only its own vehicles: the server's refusal, not told to wait
        _, op = await make_user(c, "operator", [vid])
        token = op["Authorization"].removeprefix("Bearer ")
        refused = await fleetctl(base, token, "watch", "vehicle/nosuch/telemetry",
                                 "--seconds", "0.5")  # fmt: skip
        assert refused.exit_code == 1, refused.output
        assert "warning" not in refused.stderr and "registers" not in refused.stderr
        assert "nosuch" in refused.stderr and refused.stdout == ""


async def test_a_vehicle_segment_that_is_neither_a_name_nor_an_id_is_refused_unwarned(
    make_settings: Callable[..., Settings],
) -> None:
    """``vehicle/Bad/telemetry``: no vehicle goes by ``Bad``, and no id can hold an
    uppercase letter. It is refused (exit 2) without first being warned of as a vehicle
    that may register later; a bad part past the vehicle is refused before any look-up."""
    async with served_vehicle(make_settings(), name="Kestrel") as (base, _, vid, _, _):
        bad = await fleetctl(base, ADMIN_TOKEN, "watch", "vehicle/Bad/telemetry", "--seconds", "1")
        assert bad.exit_code == 2, bad.output
        assert "warning" not in bad.stderr and "registers" not in bad.stderr
        assert "no vehicle you can see goes by 'Bad'" in bad.stderr
        assert "may hold only a-z" in bad.stderr and bad.stdout == ""
        kestrel = await fleetctl(
            base, ADMIN_TOKEN, "watch", f"vehicle/{vid}/Tele", "--seconds", "1"
        )
        assert kestrel.exit_code == 2 and "segment 'Tele'" in kestrel.stderr, kestrel.output
    nowhere = "http://127.0.0.1:9"  # nothing is asked of a server: refused all the same
    named = await fleetctl(nowhere, ADMIN_TOKEN, "watch", "vehicle/Kestrel/Tele", "--seconds", "1")
    assert named.exit_code == 2 and "segment 'Tele'" in named.stderr, named.output


async def test_count_counts_the_lines_printed(make_settings: Callable[..., Settings]) -> None:
    """``--count N`` ends the watch once N lines are printed: a vehicle's commands (and the
    fleet) come as one event of a line each, and ``--count 3`` printed every line of it,
    then waited for two more events."""
    async with served_vehicle(make_settings()) as (base, c, vid, _, _):
        other, oh = await make_vehicle(c)
        await start_instance(c, other, oh)
        for _ in range(4):
            assert (await fleetctl(base, ADMIN_TOKEN, "stop", vid)).exit_code == 0
        topic = f"vehicle/{vid}/commands"
        # --seconds: a bound should it wait (it waited for ever)
        three = await fleetctl(base, ADMIN_TOKEN, "watch", topic, "--count", "3", "--seconds", "20")
        assert three.exit_code == 0, three.output
        lines = three.stdout.splitlines()
        assert len(lines) == 3 and all(f"current {vid} commands stop " in line for line in lines)
        one = await fleetctl(base, ADMIN_TOKEN, "watch", "fleet", "--count", "1", "--seconds", "20")
        assert one.exit_code == 0 and len(one.stdout.splitlines()) == 1, one.output
        as_json = await fleetctl(base, ADMIN_TOKEN, "watch", topic, "--count", "1", "--json")
        assert json.loads(as_json.stdout)["snapshot"] is True  # an event, a line
