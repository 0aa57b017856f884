"""A command lane (this replica's copy of an instance's active commands), pure: no store."""

from __future__ import annotations

from server.domain import commands as life
from server.domain.commands import Command
from server.services.lanes import Lane
from tests.domain.test_command_life import later, make_command


def _stored(cmd: Command) -> Command:
    """The store's copy of ``cmd`` as it is now (a read of ``commands_active``)."""
    return Command.from_doc(cmd.to_doc())


def _executing() -> tuple[Lane, Command, Command]:
    """A lane with a go_to handed out and under way; and the store's copy of it."""
    lane = Lane("i-1")
    cmd = make_command()
    lane.add(cmd)
    life.mark_delivered(cmd, later(1))
    life.apply_ack(cmd, "executing", later(2))
    return lane, cmd, _stored(cmd)


def test_a_command_ended_here_is_not_taken_back_while_the_store_still_lists_it() -> None:
    """A cancel retires the command before the store has written its end: a poll reading
    the store in between must not bring it back, nor tell its abort a second time."""
    lane, cmd, stored = _executing()
    cmd.move("cancelled", later(3))
    lane.retire(cmd)
    assert lane.merge([stored]) == []  # the end on its way to the store
    assert cmd.command_id not in lane.active
    assert lane.take_aborts() == [cmd.command_id]
    assert lane.merge([]) == []  # the store holds the end now
    assert lane.take_aborts() == []


def test_a_command_ended_on_another_replica_is_given_back_for_its_end() -> None:
    """The store no longer lists a command this lane holds (another replica ended it):
    merge gives back this lane's copy, for the caller to read its end and retire it."""
    lane, cmd, _ = _executing()
    assert lane.merge([]) == [cmd]
    cmd.move("cancelled", later(3))  # as read from the store
    lane.retire(cmd)
    assert lane.active == {} and lane.take_aborts() == [cmd.command_id]
    assert lane.merge([]) == [] and lane.take_aborts() == []


def test_a_command_queued_on_another_replica_joins_the_lane() -> None:
    lane, cmd, stored = _executing()
    newcomer = _stored(make_command())
    assert lane.merge([stored, newcomer]) == []
    assert list(lane.active) == [cmd.command_id, newcomer.command_id]
    assert lane.active[cmd.command_id] is cmd  # its own copy kept, caught up
