"""The failsafe after a cut link, end to end (``harbour.py``): each action a vehicle's
policy may name (keep station, stop, return home, none) taken once the link is lost,
judged on the positions the server stored, and a policy changed while the vehicle runs
reaching it."""

from __future__ import annotations

from typing import Any

import pytest

from fleet_protocol import parse_ts
from tests.agent.harbour import DRIFT, Boat, Harbour, sail_east, until, until_async
from tests.factories import ADMIN


async def cut_and_mend(h: Harbour, boat: Boat, sim_seconds: float) -> tuple[float, float]:
    """Cut the boat's link, let ``sim_seconds`` of its time pass once its failsafe time
    is up, mend the link; the boat's local position when the failsafe time was up."""
    boat.link.cut = True
    await until(lambda: boat.agent.helm.link.lost, "the agent to find the link lost")
    engaged_at = boat.agent.adapter.sim.position  # type: ignore[attr-defined]
    begun = boat.sim_s
    await until(lambda: boat.sim_s >= begun + sim_seconds, f"{sim_seconds} s of the boat's time")
    boat.link.cut = False
    return boat.enu({"lat": engaged_at[0], "lon": engaged_at[1]})


async def stored_after(h: Harbour, boat: Boat, seq: int, count: int) -> list[dict[str, Any]]:
    """The stored samples after ``seq``, once at least ``count`` of them are in."""
    found: list[dict[str, Any]] = []

    async def enough() -> bool:
        nonlocal found
        found = [s for s in await h.telemetry(boat) if s["seq"] > seq]
        return len(found) >= count

    await until_async(enough, f"{count} samples from the outage stored")
    return found


@pytest.mark.parametrize("action", ["keep_station", "stop", "return_home", "none"])
async def test_each_failsafe_action_after_a_cut_link(harbour: Harbour, action: str) -> None:
    h = harbour
    boat = await h.boat(
        f"fs-{action.replace('_', '-')}",
        current=DRIFT,
        # 1.5 s of silence (60 s of the boat's time): 0.5 s was taken for a cut link in a
        # loaded make test, and the boat was in failsafe before it sailed.
        failsafe={"action": action, "after_s": 1.5},
    )
    policy = await h.call("GET", f"/api/vehicles/{boat.vehicle_id}/failsafe")
    assert policy["failsafe"]["action"] == action and policy["failsafe"]["version"] == 1

    async def acked() -> bool:
        view = await h.call("GET", f"/api/vehicles/{boat.vehicle_id}")
        return view["failsafe_acked"] is True

    await until_async(acked, "the vehicle to acknowledge its policy")
    op = await h.operator(boat)
    command_id = await sail_east(h, boat, op)
    seq_at_cut = boat.agent.outbox.next_seq - 1
    engaged = await cut_and_mend(h, boat, sim_seconds=200.0)
    samples = await stored_after(h, boat, seq_at_cut, count=40)
    # Judge the last positions of the outage as the server stored them.
    tail = [boat.enu(s) for s in samples[-10:]]
    east, north = tail[-1]
    if action == "none":
        assert east > engaged[0] + 30, "with none the boat carries on east"
        assert (await h.command(command_id))["status"] in ("executing", "done")
    elif action == "return_home":
        assert east**2 + north**2 <= 3.0**2, f"home is (0, 0); the boat is at {tail[-1]}"
    elif action == "keep_station":
        assert all(((e - engaged[0]) ** 2 + (n - engaged[1]) ** 2) ** 0.5 <= 5 for e, n in tail)
    else:  # stop: thrust off, the current carries it north, it goes no further east
        assert north > engaged[1] + 3, "a stopped boat drifts with the current"
        assert east < engaged[0] + 10
    if action != "none":
        assert (await h.command(command_id))["status"] == "failed"

        async def recorded() -> bool:
            return bool(await h.events(boat, "failsafe_entered"))

        await until_async(recorded, "failsafe_entered recorded once the link is back")
        entered = await h.events(boat, "failsafe_entered")
        assert entered[0]["data"]["control_mode"] == "failsafe"
        # Dated when the boat took it, 200 s of its time (5 s here) before the link
        # was back and the server heard of it.
        waited = parse_ts(entered[0]["at"]) - parse_ts(entered[0]["data"]["since"])
        assert waited.total_seconds() >= 4.5, entered[0]


async def test_a_policy_changed_while_running_reaches_the_vehicle(harbour: Harbour) -> None:
    h = harbour
    boat = await h.boat("fs-change")
    assert boat.agent.helm.pilot.failsafe.version == 0  # the server's default until set
    r = await h.http.put(
        f"/api/vehicles/{boat.vehicle_id}/failsafe",
        headers=ADMIN,
        json={"action": "return_home", "after_s": 12, "home": boat.at(5, 5)},
    )
    assert r.status_code == 200, r.text
    await until(lambda: boat.agent.helm.pilot.failsafe.version == 1, "the new policy applied")
    assert boat.agent.helm.pilot.failsafe.action == "return_home"
    assert boat.agent.helm.link.after_s == 12

    async def acked() -> bool:
        view = await h.call("GET", f"/api/vehicles/{boat.vehicle_id}/failsafe")
        return view["acked"] is True and view["acked_version"] == 1

    await until_async(acked, "the acknowledgement recorded")
