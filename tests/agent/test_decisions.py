"""The agent's pure decisions: commands, aborts, reports, link loss, clock."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

from fleet_protocol import CommandObject, FailsafePolicy, FbAck
from vehicle_client.clock import ServerClock
from vehicle_client.decisions import Execute, Halt, LinkMonitor, Pilot, next_tick, order_commands
from vehicle_client.sim.simulator import TaskReport

NOW = datetime(2026, 11, 22, 10, 0, 0, tzinfo=UTC)
ALL = frozenset({"stop", "go_to", "keep_station", "follow_path"})
GO = {"lat": 43.9, "lon": 15.4}
_counter = iter(range(1_000_000))


def make_command(kind: str = "go_to", args: dict | None = None, **fields) -> CommandObject:
    n = next(_counter)
    defaults = {
        "command_id": f"c{n}",
        "instance_id": "i1",
        "type": kind,
        "args": args
        if args is not None
        else ({"lat": 43.9, "lon": 15.4} if kind == "go_to" else {}),
        "status": "delivered",
        "issued_by": "op",
        "issued_at": NOW - timedelta(seconds=10) + timedelta(milliseconds=n),
        "expires_at": NOW + timedelta(seconds=30),
    }
    return CommandObject.model_validate({**defaults, **fields})


def acks(effects) -> list[tuple[str, str]]:
    return [(e.command_id, e.status) for e in effects if isinstance(e, FbAck)]


def test_stop_comes_first_then_oldest_first() -> None:
    old = make_command("go_to", issued_at=NOW - timedelta(minutes=5))
    new = make_command("keep_station")
    stop = make_command("stop", issued_at=NOW)
    assert [c.command_id for c in order_commands([new, stop, old])] == [
        stop.command_id,
        old.command_id,
        new.command_id,
    ]


def test_a_command_is_accepted_executed_and_marked_seen() -> None:
    pilot = Pilot(ALL)
    cmd = make_command("go_to")
    effects = pilot.on_commands([cmd], NOW)
    assert acks(effects) == [(cmd.command_id, "accepted"), (cmd.command_id, "executing")]
    assert Execute("go_to", cmd.args, cmd.command_id) in effects
    assert pilot.control_mode == "remote"
    assert pilot.seen[cmd.command_id] == "executing"


def test_a_command_past_its_expiry_by_server_clock_is_rejected() -> None:
    pilot = Pilot(ALL)
    cmd = make_command(expires_at=NOW - timedelta(milliseconds=1))
    effects = pilot.on_commands([cmd], NOW)
    assert acks(effects) == [(cmd.command_id, "rejected")]
    assert not any(isinstance(e, Execute) for e in effects)


def test_a_repeated_command_is_not_executed_again_but_its_status_is_acked_again() -> None:
    pilot = Pilot(ALL)
    cmd = make_command("go_to")
    pilot.on_commands([cmd], NOW)
    assert pilot.on_report(TaskReport("stop", "done")) == []  # not the active task's
    assert acks(pilot.on_report(TaskReport("go_to", "done"))) == [(cmd.command_id, "done")]
    again = pilot.on_commands([cmd], NOW)
    assert acks(again) == [(cmd.command_id, "done")]
    assert not any(isinstance(e, Execute) for e in again)


def test_seen_ids_survive_in_the_mapping_given_to_a_new_pilot() -> None:
    store: dict[str, str] = {}
    cmd = make_command("go_to")
    Pilot(ALL, seen=store).on_commands([cmd], NOW)
    restarted = Pilot(ALL, seen=store)
    assert not any(isinstance(e, Execute) for e in restarted.on_commands([cmd], NOW))


def test_a_command_interrupted_by_a_restart_is_reported_failed() -> None:
    pilot = Pilot(ALL)
    assert acks(pilot.on_restart(["c-old"])) == [("c-old", "failed")]


def test_missing_capability_and_bad_args_are_rejected() -> None:
    pilot = Pilot(frozenset({"stop", "go_to"}))
    path = make_command("follow_path", args={"waypoints": [{"lat": 1, "lon": 2}]})
    bad = make_command("go_to", args={"lat": 123.0, "lon": 0.0})
    assert acks(pilot.on_commands([path, bad], NOW)) == [
        (path.command_id, "rejected"),
        (bad.command_id, "rejected"),
    ]


def test_stop_ends_the_active_command_and_is_taken_under_local_control() -> None:
    pilot = Pilot(ALL)
    go = make_command("go_to")
    pilot.on_commands([go], NOW)
    pilot.local_control = True
    refused = make_command("keep_station")
    stop = make_command("stop")
    effects = pilot.on_commands([refused, stop], NOW)
    assert acks(effects) == [
        (go.command_id, "failed"),
        (stop.command_id, "accepted"),
        (stop.command_id, "executing"),
        (refused.command_id, "rejected"),
    ]
    assert pilot.control_mode == "local"


def test_reports_become_progress_acks_then_done() -> None:
    pilot = Pilot(ALL)
    path = make_command("follow_path", args={"waypoints": [{"lat": 1, "lon": 2}]})
    pilot.on_commands([path], NOW)
    first = pilot.on_report(TaskReport("follow_path", "executing", 0.10))
    tiny = pilot.on_report(TaskReport("follow_path", "executing", 0.11))
    later = pilot.on_report(TaskReport("follow_path", "executing", 0.30))
    done = pilot.on_report(TaskReport("follow_path", "done", 1.0))
    assert [a.progress for a in first + later] == [0.1, 0.3]
    assert tiny == []
    assert acks(done) == [(path.command_id, "done")]
    assert pilot.control_mode == "idle"


def test_abort_halts_the_active_command_and_silences_it() -> None:
    pilot = Pilot(ALL)
    go = make_command("go_to")
    pilot.on_commands([go], NOW)
    assert pilot.on_abort([go.command_id, "never-seen"]) == [Halt()]
    assert pilot.on_report(TaskReport("go_to", "done")) == []
    assert pilot.on_commands([go], NOW) == []
    assert pilot.on_abort([go.command_id]) == []


def test_link_loss_runs_the_failsafe_until_the_next_command() -> None:
    pilot = Pilot(ALL, failsafe=FailsafePolicy(after_s=30, action="keep_station"))
    go = make_command("go_to")
    pilot.on_commands([go], NOW)
    effects = pilot.on_link_lost()
    assert acks(effects) == [(go.command_id, "failed")]
    assert Execute("keep_station", {}) in effects
    assert pilot.control_mode == "failsafe"
    pilot.on_commands([make_command("go_to")], NOW)
    assert pilot.control_mode == "remote"


def test_link_monitor_fires_once_on_loss_and_once_on_return() -> None:
    link = LinkMonitor(after_s=30)
    assert link.poll(0.0) is None  # never connected yet: nothing to lose
    link.contact(0.0)
    assert link.poll(29.9) is None
    assert link.poll(30.0) == "lost"
    assert link.poll(60.0) is None
    assert link.contact(61.0) == "restored"
    assert link.contact(62.0) is None


def test_server_clock_offset_corrects_local_time() -> None:
    clock = ServerClock()
    sent = NOW
    received = NOW + timedelta(seconds=2)
    clock.observe(NOW + timedelta(seconds=61), sent, received)
    assert clock.offset_s == 60.0
    assert clock.server_now(NOW) == NOW + timedelta(seconds=60)


def test_the_sampling_clock_keeps_its_beat_and_skips_what_a_stall_missed() -> None:
    assert next_tick(10.0, 10.01, 0.5) == 10.5  # on time: a period on
    assert next_tick(10.0, 10.3, 0.5) == 10.5  # a little late: the beat is kept
    # Stopped for 20 s at 2 Hz: the next sample a period from now, not 40 at once.
    woke = 30.0
    assert next_tick(10.0, woke, 0.5) == woke + 0.5
    due = next_tick(10.0, woke, 0.5)
    for _ in range(3):  # then on the beat again, from the wake
        now = due
        due = next_tick(due, now, 0.5)
        assert due == now + 0.5
