"""Command life cycle, pure: acks, expiry, redelivery, drift, queue order, stop."""

from __future__ import annotations

import itertools
from datetime import UTC, datetime, timedelta
from typing import Any

import pytest

from server.domain import command_ends as ends
from server.domain import commands as life
from server.domain.commands import AckOutcome, Command
from server.errors import CapabilityMissing

T0 = datetime(2026, 11, 22, 10, 0, 0, tzinfo=UTC)
_seq = itertools.count(1)


def make_command(
    type: str = "go_to",
    *,
    at: datetime = T0,
    ttl_s: float = 30,
    issued_by: str = "alice",
    max_drift_m: float | None = None,
    position: dict[str, Any] | None = None,
) -> Command:
    seq = next(_seq)
    args = {"lat": 43.9, "lon": 15.4} if type == "go_to" else {}
    return life.new_command(
        command_id=f"c-{seq}",
        instance_id="i-1",
        vehicle_id="usv-1",
        type=type,
        args=args,
        issued_by=issued_by,
        now=at,
        ttl_s=ttl_s,
        seq=seq,
        max_drift_m=max_drift_m,
        position=position,
    )


def later(seconds: float) -> datetime:
    return T0 + timedelta(seconds=seconds)


def hand_out(
    cmds: list[Command],
    at: datetime,
    *,
    position: dict[str, Any] | None = None,
    ack_timeout_s: float = 10,
) -> tuple[list[Command], list[Command]]:
    return life.handout(cmds, at, ack_timeout_s=ack_timeout_s, position=position)


def test_a_new_command_is_queued_with_one_history_entry() -> None:
    cmd = make_command()
    assert cmd.status == "queued"
    assert [h["status"] for h in cmd.history] == ["queued"]
    assert cmd.expires_at == later(30)


def test_acks_move_forward_through_the_cycle() -> None:
    cmd = make_command()
    hand_out([cmd], later(1))
    for status in ("accepted", "executing", "done"):
        assert life.apply_ack(cmd, status, later(2)) is AckOutcome.APPLIED
    assert cmd.status == "done"
    assert [h["status"] for h in cmd.history] == [
        "queued",
        "delivered",
        "accepted",
        "executing",
        "done",
    ]


def test_a_backward_ack_is_recorded_and_ignored() -> None:
    cmd = make_command()
    life.apply_ack(cmd, "executing", later(1))
    assert life.apply_ack(cmd, "accepted", later(2)) is AckOutcome.BACKWARD
    assert cmd.status == "executing"
    assert cmd.history[-1]["status"] == "ack:accepted"
    assert "backward" in cmd.history[-1]["detail"]


def test_ignored_acks_cannot_grow_a_command_without_bound() -> None:
    """A repeat of the entry before it is not kept, and a command keeps 16 ignored acks at
    most: a vehicle re-sending its last 'done' every second (or a token flooding acks of
    512 characters) grew one command to 11,825 entries and 7 MB."""
    cmd = make_command()
    for status in ("accepted", "executing", "done"):
        life.apply_ack(cmd, status, later(1))
    moved = len(cmd.history)
    for n in range(3):
        assert life.apply_ack(cmd, "done", later(2 + n)) is AckOutcome.LATE
    assert len(cmd.history) == moved + 1  # the same late ack, kept once
    for n in range(100):
        life.apply_ack(cmd, "done", later(10 + n), detail=f"again {n}")
    assert len(cmd.history) == moved + life.IGNORED_KEPT
    assert cmd.status == "done"


def test_an_ack_for_a_final_command_is_recorded_and_leaves_the_status() -> None:
    cmd = make_command()
    assert ends.cancel(cmd, later(1), "by alice")
    assert life.apply_ack(cmd, "accepted", later(2)) is AckOutcome.LATE
    assert cmd.status == "cancelled"
    assert cmd.history[-1]["status"] == "ack:accepted"


def test_repeated_progress_reports_update_progress_without_history() -> None:
    cmd = make_command()
    life.apply_ack(cmd, "executing", later(1), progress=10)
    entries = len(cmd.history)
    life.apply_ack(cmd, "executing", later(2), progress=40)
    assert cmd.progress == 40
    assert len(cmd.history) == entries


def test_progress_never_goes_back_and_done_is_all_of_it() -> None:
    cmd = make_command()
    life.apply_ack(cmd, "executing", later(1), progress=0.8)
    life.apply_ack(cmd, "executing", later(2), progress=0.3)  # overtaken on the way
    assert cmd.progress == 0.8
    life.apply_ack(cmd, "done", later(3), progress=0.5)
    assert (cmd.status, cmd.progress) == ("done", 1.0)


def test_an_unacknowledged_command_expires_handed_out_or_not() -> None:
    waiting, handed = make_command(ttl_s=5), make_command(ttl_s=5)
    hand_out([handed], later(1))
    assert life.expire_if_due(waiting, later(5))
    assert life.expire_if_due(handed, later(5))
    assert waiting.status == handed.status == "expired"


def test_an_accepted_command_does_not_expire() -> None:
    cmd = make_command(ttl_s=5)
    life.apply_ack(cmd, "accepted", later(1))
    assert not life.expire_if_due(cmd, later(60))
    assert cmd.status == "accepted"


def test_an_expired_command_is_never_handed_out() -> None:
    cmd = make_command(ttl_s=5)
    out, ended = hand_out([cmd], later(6))
    assert out == []
    assert ended == [cmd]
    assert cmd.status == "expired"


def test_a_handed_out_command_is_redelivered_once_per_ack_timeout() -> None:
    cmd = make_command(ttl_s=100)
    assert hand_out([cmd], later(0))[0] == [cmd]
    assert hand_out([cmd], later(9))[0] == []
    assert hand_out([cmd], later(10))[0] == [cmd]
    assert hand_out([cmd], later(15))[0] == []
    assert hand_out([cmd], later(20))[0] == [cmd]
    assert cmd.deliveries == 3
    assert cmd.status == "delivered"
    assert cmd.history[-1]["detail"] == "redelivery 2"


def test_an_acknowledged_command_is_not_redelivered() -> None:
    cmd = make_command(ttl_s=100)
    hand_out([cmd], later(0))
    life.apply_ack(cmd, "accepted", later(1))
    assert hand_out([cmd], later(50))[0] == []


def test_stop_is_handed_out_first_then_oldest_first() -> None:
    old = make_command("go_to", at=later(0))
    newer = make_command("keep_station", at=later(1))
    stop = make_command("stop", at=later(2))
    out, _ = hand_out([newer, stop, old], later(3))
    assert out == [stop, old, newer]


def test_stop_cancels_the_motion_queued_before_it_only() -> None:
    before = make_command("go_to", at=later(0))
    accepted = make_command("go_to", at=later(0))
    life.apply_ack(accepted, "accepted", later(0))
    stop = make_command("stop", at=later(1))
    after = make_command("go_to", at=later(2))
    gone = ends.supersede([before, accepted, after], stop, later(2))
    assert gone == [before]
    assert before.status == "cancelled"
    assert before.history[-1]["detail"] == "superseded_by_stop"
    assert accepted.status == "accepted"
    assert after.status == "queued"


def test_stops_sent_again_while_none_is_handed_out_wait_as_one() -> None:
    """The latest stop stands for the queued ones it outlasts; never for one handed out
    (its ack may be on its way), one that would outlast it, or a manager's for another's."""
    first = make_command("stop", at=later(0), ttl_s=30)
    longer = make_command("stop", at=later(1), ttl_s=3600)
    handed = make_command("stop", at=later(1))
    hand_out([handed], later(1))
    managers = make_command("stop", at=later(1))
    managers.by_manager = True
    stop = make_command("stop", at=later(2), ttl_s=60)
    gone = ends.supersede([first, longer, handed, managers], stop, later(2))
    assert gone == [first] and first.history[-1]["detail"] == "superseded_by_stop"
    assert (longer.status, handed.status, managers.status) == ("queued", "delivered", "queued")
    stop.by_manager = True  # a manager's stop stands for a manager's
    assert ends.supersede([managers], stop, later(2)) == [managers]


def test_a_mission_the_vehicle_ended_for_a_newer_command_is_superseded_not_failed() -> None:
    running = make_command("go_to", at=later(0))
    life.apply_ack(running, "executing", later(1))
    status, detail = life.superseded("failed", "superseded by keep_station c-9")
    assert (status, detail) == ("cancelled", "superseded_by keep_station c-9")
    life.apply_ack(running, status, later(2), detail=detail)
    assert running.status == "cancelled" and running.final
    # a real failure stays one
    assert life.superseded("failed", "the thruster stalled") == ("failed", "the thruster stalled")
    assert life.superseded("done", "superseded by x") == ("done", "superseded by x")


def test_a_command_is_expired_as_drifted_when_the_vehicle_moved_too_far() -> None:
    here = {"lat": 43.9, "lon": 15.4}
    cmd = make_command(max_drift_m=50, position=here)
    near = {"lat": 43.9002, "lon": 15.4}  # about 22 m north
    far = {"lat": 43.901, "lon": 15.4}  # about 111 m north
    assert not life.drifted(cmd, near)
    out, ended = hand_out([cmd], later(1), position=far)
    assert out == []
    assert ended == [cmd]
    assert cmd.status == "expired"
    assert cmd.history[-1]["detail"] == "drifted"


def test_drift_is_not_judged_without_a_known_position() -> None:
    cmd = make_command(max_drift_m=50, position=None)
    assert hand_out([cmd], later(1), position={"lat": 0, "lon": 0})[0] == [cmd]


def test_every_vehicle_can_stop_and_nothing_else_without_the_capability() -> None:
    life.check_capability("stop", [])
    life.check_capability("go_to", ["go_to"])
    with pytest.raises(CapabilityMissing):
        life.check_capability("follow_path", ["go_to"])


def test_a_command_survives_the_round_trip_through_its_document() -> None:
    cmd = make_command(max_drift_m=10, position={"lat": 1.0, "lon": 2.0})
    hand_out([cmd], later(1))
    again = Command.from_doc(cmd.to_doc())
    assert again == cmd
