"""Control that ends safely, end to end (``harbour.py``): a lease revoked, or lapsed for
its operator's silent client, leaves the vehicle holding station where it was."""

from __future__ import annotations

import asyncio
import contextlib
from typing import Any

from tests.agent.harbour import DRIFT, Boat, Harbour, held_within, sail_east, until_async


async def holding(h: Harbour, boat: Boat) -> dict[str, Any]:
    """The system's keep_station, once the vehicle executes it."""
    found: dict[str, Any] = {}

    async def executing() -> bool:
        events = await h.events(boat, "hold_station")
        if not events or events[0]["data"]["command_id"] is None:
            return False
        found.update(await h.command(events[0]["data"]["command_id"]))
        return found["status"] == "executing"

    await until_async(executing, "the vehicle holding station")
    return found


async def test_a_revoked_lease_leaves_the_vehicle_holding_station(harbour: Harbour) -> None:
    h = harbour
    boat = await h.boat("hold-revoke", current=DRIFT)
    op = await h.operator(boat)
    go = await sail_east(h, boat, op)
    await h.call("POST", "/client/revoke_control", json={"instance_id": boat.instance_id})
    hold = await holding(h, boat)
    assert hold["type"] == "keep_station" and hold["issued_by"] == "system"
    replaced = await h.command(go)  # the vehicle ended it for the hold: superseded
    assert replaced["status"] == "cancelled", replaced
    assert replaced["history"][-1]["detail"].startswith("superseded_by keep_station c-")
    (event,) = await h.events(boat, "hold_station")
    assert event["data"]["reason"] == "revoked" and event["data"]["holder"].startswith("op-")
    await held_within(h, boat, metres=3.0, sim_seconds=60.0)


async def test_a_silent_operator_client_ends_the_lease_and_the_vehicle_holds(
    harbour: Harbour,
) -> None:
    h = harbour
    boat = await h.boat("hold-silent", current=DRIFT)
    op = await h.operator(boat, operator_timeout_s=2)

    async def heartbeats() -> None:  # the operator's client, alive
        while True:
            r = await h.http.post(
                "/client/heartbeat", headers=op, json={"instance_ids": [boat.instance_id]}
            )
            assert r.json()["held"] == [boat.instance_id]
            await asyncio.sleep(0.5)

    client = asyncio.create_task(heartbeats())
    try:
        await sail_east(h, boat, op)
        lease = (await h.call("GET", f"/api/vehicles/{boat.vehicle_id}"))["control"]
        assert lease["operator_timeout_s"] == 2
    finally:
        client.cancel()  # the client dies mid-mission
        with contextlib.suppress(asyncio.CancelledError):
            await client

    async def lapsed() -> bool:
        events = await h.events(boat, "control_expired")
        return any(e["data"].get("reason") == "operator_silent" for e in events)

    await until_async(lapsed, "the lease to lapse for the operator's silence")
    hold = await holding(h, boat)
    assert hold["type"] == "keep_station"
    await held_within(h, boat, metres=3.0, sim_seconds=40.0)
    r = await h.try_submit(op, boat, "go_to", boat.at(0, 0))
    assert r.status_code == 409  # the lease is gone
