"""Plans that arrive whole, end to end (``harbour.py``): a path received in part is never
run, and a vehicle that acknowledges another plan's hash fails the command and stops."""

from __future__ import annotations

from typing import Any

from tests.agent.harbour import Harbour, until_async


async def test_a_plan_received_in_part_never_runs(harbour: Harbour) -> None:
    h = harbour
    boat = await h.boat("plan-cut")
    op = await h.operator(boat)

    def drop_last_waypoint(path: str, body: dict[str, Any]) -> dict[str, Any]:
        for cmd in body.get("commands") or []:
            if path.endswith("/get_control") and cmd["type"] == "follow_path":
                cmd["args"]["waypoints"] = cmd["args"]["waypoints"][:-1]
        return body

    boat.link.rewrite = drop_last_waypoint
    waypoints = [boat.at(100, 0), boat.at(100, 100), boat.at(0, 100)]
    command_id = await h.submit(op, boat, "follow_path", {"waypoints": waypoints})

    async def ended() -> bool:
        return (await h.command(command_id))["status"] in ("rejected", "failed", "done")

    await until_async(ended, "the vehicle's answer")
    cmd = await h.command(command_id)
    assert cmd["status"] == "rejected"
    assert cmd["history"][-1]["detail"].startswith("plan_mismatch")
    assert cmd["args"]["path_hash"].startswith("sha256:")
    e, n = await h.position(boat)
    assert e**2 + n**2 <= 1.0, "the boat never set out"
    boat.link.rewrite = None
    whole = await h.submit(op, boat, "follow_path", {"waypoints": waypoints[:1]})

    async def accepted() -> bool:
        return (await h.command(whole))["status"] in ("executing", "done")

    await until_async(accepted, "a whole plan accepted")


async def test_a_vehicle_acknowledging_another_hash_fails_the_command(harbour: Harbour) -> None:
    h = harbour
    boat = await h.boat("plan-hash")
    op = await h.operator(boat)
    original = boat.agent.helm.pilot._ack

    def lying_ack(command_id: str, status: str, **extra: Any) -> Any:
        if extra.get("path_hash"):
            extra["path_hash"] = "sha256:" + "0" * 64
        return original(command_id, status, **extra)

    boat.agent.helm.pilot._ack = lying_ack  # type: ignore[method-assign]
    command_id = await h.submit(op, boat, "follow_path", {"waypoints": [boat.at(200, 0)]})

    async def failed() -> bool:
        return (await h.command(command_id))["status"] == "failed"

    await until_async(failed, "the command failed")
    cmd = await h.command(command_id)
    failed_entry = next(e for e in cmd["history"] if e["status"] == "failed")
    assert failed_entry["detail"].startswith("plan_mismatch")

    async def halted() -> bool:  # the abort reached the vehicle: it stopped the task
        return boat.agent.helm.pilot.active_id is None

    await until_async(halted, "the vehicle told to abort")
