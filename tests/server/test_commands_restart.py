"""Hot state survives a clean restart: queued commands, leases, finished history."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from server.settings import Settings
from tests.factories import ADMIN, FakeClock
from tests.server.commanding import GO_TO, Person, Vehicle, World, statuses, world

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


async def test_queues_and_leases_survive_a_clean_restart(
    make_settings: Callable[..., Settings],
) -> None:
    settings, clock = make_settings(), FakeClock()
    async with world(settings, clock) as w:
        v, op, running, dropped, waiting = await _one_of_each(w)
    async with world(settings, clock) as w:
        assert statuses(await w.command(running)) == ["queued", "delivered", "accepted"]
        assert (await w.command(dropped))["status"] == "cancelled"
        assert [c["command_id"] for c in await w.poll(v)] == [waiting]
        assert (await w.submit(op, [v], GO_TO)).status_code == 202  # the lease is still held
        for _ in range(2):  # read back from the store once, then kept in memory
            r = await w.http.get(
                "/client/get_fbmessage", headers=op.headers, params={"instance_id": v.instance_id}
            )
            assert dropped in [c["command_id"] for c in r.json()["commands"]]
            assert len(r.json()["commands"]) == 4


async def test_what_was_answered_outlives_a_crash(
    make_settings: Callable[..., Settings],
) -> None:
    """The server dies with no time to flush (the journal's own flush an hour away): a
    command answered 202, a vehicle's ack answered 200 and a cancel answered are on disk
    for the server that starts next (on MongoDB, an acknowledged write is)."""
    settings, clock = make_settings(snapshot_interval_s=3600), FakeClock()
    async with world(settings, clock) as w:
        _, _, running, dropped, waiting = await _one_of_each(w)
        # Another server starts on what is on disk while this one still runs: as after a
        # SIGKILL, nothing this one holds in memory reaches the next.
        async with world(settings, clock) as after:
            assert statuses(await after.command(running))[-1] == "accepted"
            assert (await after.command(waiting))["status"] == "queued"
            assert (await after.command(dropped))["status"] == "cancelled"


async def _one_of_each(w: World) -> tuple[Vehicle, Person, str, str, str]:
    """A vehicle under an operator's lease with a command accepted, one cancelled and
    one queued: ``(vehicle, operator, running, dropped, waiting)``."""
    v = await w.vehicle()
    op = await w.operator_in_control(v, duration_s=600)
    running = await w.queued(op, v, GO_TO, ttl_s=600)
    await w.poll(v)
    await w.ack(v, (running, "accepted"))
    dropped = await w.queued(op, v, GO_TO, ttl_s=600)
    r = await w.http.post(
        "/client/cancel_command", headers=op.headers, json={"command_id": dropped}
    )
    assert r.status_code == 200, r.text
    waiting = await w.queued(op, v, GO_TO, ttl_s=600)
    return v, op, running, dropped, waiting


async def test_a_restart_gives_a_lease_needing_a_live_client_its_timeout_again(
    make_settings: Callable[..., Settings],
) -> None:
    """The server was down longer than the holder's ``operator_timeout_s``: its client had
    nothing to reach. The server that starts counts the client as heard then, and the lease
    lapses only if the client stays silent for the timeout after that."""
    settings, clock = make_settings(), FakeClock()
    async with world(settings, clock) as w:
        v = await w.vehicle()
        op = await w.person("operator", v)
        body = {
            "instance_id": v.instance_id,
            "user": op.username,
            "duration_s": 600,
            "operator_timeout_s": 10,
        }
        assert (await w.http.post("/client/grant_control", headers=ADMIN, json=body)).is_success
    clock.advance(60)  # down for a minute
    async with world(settings, clock) as w:
        assert (await w.submit(op, [v], GO_TO)).status_code == 202  # still the holder
        clock.advance(11)  # and now silent for longer than its timeout
        await w.services.control.sweep()
        r = await w.http.post(
            "/client/connect_instance", headers=ADMIN, json={"instance_id": v.instance_id}
        )
        assert r.json()["instance"]["control"] is None
        events = (
            await w.http.get("/api/events", headers=ADMIN, params={"kind": "control_expired"})
        ).json()["events"]
        assert [e["data"]["reason"] for e in events] == ["operator_silent"]
