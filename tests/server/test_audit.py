"""The control log through HTTP: one chain per vehicle of grants, leases and commands,
each entry holding the hash of the one before; altering a stored entry breaks it."""

from __future__ import annotations

import itertools
from collections.abc import AsyncIterator, Callable
from typing import Any

import pytest

from fleet_protocol import GENESIS, first_break
from server.settings import Settings
from tests.factories import ADMIN
from tests.server.commanding import GO_TO, World, eventually, world

pytestmark = pytest.mark.usefixtures("store_backend")


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    async with world(make_settings()) as w:
        yield w


async def chain(w: World, vehicle_id: str, who: dict[str, str] = ADMIN) -> list[dict[str, Any]]:
    entries: list[dict[str, Any]] = []
    after = 0
    while True:
        r = await w.http.get(
            f"/api/vehicles/{vehicle_id}/audit",
            headers=who,
            params={"after_seq": after, "limit": 3},
        )
        assert r.status_code == 200, r.text
        page = r.json()
        entries += page["entries"]
        if page["next_after_seq"] is None:
            return entries
        after = page["next_after_seq"]


async def test_grants_commands_and_the_lease_end_make_one_chain(w: World) -> None:
    me = await w.vehicle()
    op = await w.operator_in_control(me)
    cid = await w.queued(op, me, GO_TO)
    await w.poll(me)
    await w.ack(me, (cid, "accepted"), (cid, "executing"), (cid, "done"))
    r = await w.http.post(
        "/client/revoke_control", headers=ADMIN, json={"instance_id": me.instance_id}
    )
    assert r.status_code == 200

    other = await w.person("operator", me)  # asks, and is refused: on the chain too
    r = await w.http.post(
        "/client/request_control", headers=other.headers, json={"instance_id": me.instance_id}
    )
    assert r.status_code == 200, r.text
    body = {"instance_id": me.instance_id, "user": other.username, "reason": "divers down"}
    assert (await w.http.post("/client/deny_control", headers=ADMIN, json=body)).is_success

    async def complete() -> bool:
        kinds = [e["kind"] for e in await chain(w, me.vehicle_id)]
        return "hold_station" in kinds and "control_revoke" in kinds and "control_deny" in kinds

    await eventually(complete)
    entries = await chain(w, me.vehicle_id)
    assert [e["seq"] for e in entries] == list(range(1, len(entries) + 1))
    assert entries[0]["prev_hash"] == GENESIS
    assert all(b["prev_hash"] == a["hash"] for a, b in itertools.pairwise(entries))
    assert first_break(entries) is None
    kinds = [e["kind"] for e in entries]
    assert kinds[0] == "control_grant" and entries[0]["actor"] == "admin"
    steps = [e["data"].get("status") for e in entries if e["data"].get("command_id") == cid]
    assert steps[0] == "queued" and {"delivered", "accepted", "executing", "done"} <= set(steps)
    assert kinds.index("control_revoke") < kinds.index("hold_station")


async def test_an_altered_entry_breaks_the_chain_there(w: World) -> None:
    me = await w.vehicle()
    op = await w.operator_in_control(me)
    await w.queued(op, me, GO_TO)
    await eventually(lambda: _at_least(w, me.vehicle_id, 2))
    entries = await chain(w, me.vehicle_id)
    assert first_break(entries) is None
    store = w.services.store["audit"]
    assert await store.update({"_id": f"{me.vehicle_id}/{2:012d}"}, set={"actor": "someone else"})
    broken = await chain(w, me.vehicle_id)
    assert first_break(broken) == (2, "its content does not match its hash")
    assert await store.delete({"_id": f"{me.vehicle_id}/{1:012d}"}) == 1
    assert first_break(await chain(w, me.vehicle_id))[0] == 2


async def _at_least(w: World, vehicle_id: str, n: int) -> bool:
    return len(await chain(w, vehicle_id)) >= n


async def test_only_who_sees_the_vehicle_reads_its_log(w: World) -> None:
    me, other = await w.vehicle(), await w.vehicle()
    viewer = await w.person("viewer", other)
    r = await w.http.get(f"/api/vehicles/{me.vehicle_id}/audit", headers=viewer.headers)
    assert r.status_code == 404
    r = await w.http.get(f"/api/vehicles/{other.vehicle_id}/audit", headers=viewer.headers)
    assert r.status_code == 200 and r.json() == {"entries": [], "next_after_seq": None}
