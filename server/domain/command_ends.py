"""How a command ends other than by the vehicle's acks: a stop supersedes it, someone
cancels it, its lease ends, or the vehicle resumes without it; and which of these the
vehicle must be told to abort. Pure.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable
from datetime import datetime

from fleet_protocol import MOTION_TYPES
from server.domain.commands import (
    ABORT_STATUSES,
    RANK,
    SUPERSEDED_BY,
    UNACKNOWLEDGED,
    Command,
    rank,
)
from server.errors import ControlNotHeld, Forbidden


def supersede(cmds: list[Command], stop: Command, now: datetime) -> list[Command]:
    """A ``stop`` cancels the motion commands queued before it (not yet acknowledged), and
    the stops queued before it (never handed out) that it stands for: ones that would not
    outlast it, sent by nobody of more standing (a manager's stop, which an operator may
    not cancel, is not replaced by an operator's, which it may). Stops sent again and
    again to a vehicle out of reach so wait as one, not as a growing queue."""
    gone = []
    for cmd in cmds:
        if (cmd.issued_at, cmd.seq) > (stop.issued_at, stop.seq):
            continue
        if cmd.type in MOTION_TYPES and cmd.status in UNACKNOWLEDGED:
            cmd.move("cancelled", now, "superseded_by_stop")
            gone.append(cmd)
        elif (
            cmd.is_stop
            and cmd.status == "queued"
            and cmd.expires_at <= stop.expires_at
            and (stop.by_manager or not cmd.by_manager)
        ):
            cmd.move("cancelled", now, "superseded_by_stop")
            gone.append(cmd)
    return gone


def supersede_holds(cmds: list[Command], hold: Command, now: datetime) -> list[Command]:
    """A hold the server sends (its ``keep_station``: where the vehicle is, when it starts)
    replaces the ones of its own queued before it and never handed out: leases ended one
    after the other queue one hold, not one each. Their detail names it
    (``superseded_by keep_station <command_id>``)."""
    gone = []
    for cmd in cmds:
        if cmd is hold or (cmd.issued_at, cmd.seq) > (hold.issued_at, hold.seq):
            continue
        if cmd.type == hold.type and cmd.issued_by == hold.issued_by and cmd.status == "queued":
            cmd.move("cancelled", now, f"{SUPERSEDED_BY}{hold.type} {hold.command_id}")
            gone.append(cmd)
    return gone


def check_cancel(cmd: Command, who: str, *, holds: bool, manages: bool) -> None:
    """Whether ``who`` may cancel ``cmd``: a manager of the vehicle or an admin
    (``manages``) always; else its issuer or the control holder (``holds``), except a
    stop a manager or an admin sent: nobody of lesser standing undoes it (403)."""
    if manages:
        return
    if cmd.is_stop and cmd.by_manager:
        raise Forbidden(
            "a stop sent by a manager or an admin is cancelled only by a manager of the "
            "vehicle or an admin"
        )
    if not (cmd.issued_by == who or holds):
        raise ControlNotHeld("only its issuer, the control holder or a manager cancels it")


def cancel(cmd: Command, now: datetime, detail: str) -> bool:
    if cmd.final:
        return False
    cmd.move("cancelled", now, detail)
    return True


#: The detail of a command a resuming vehicle no longer carries out.
DROPPED = "dropped: the vehicle resumed without it (its agent restarted or lost it)"


def ended_by_server(cmd: Command) -> bool:
    """Whether ``cmd`` ended on the server's word, not the vehicle's (``expired``,
    ``cancelled``, or ``failed`` as :data:`DROPPED`): a vehicle still carrying it out
    must drop it (``abort``)."""
    if cmd.status in ABORT_STATUSES:
        return True
    return cmd.status == "failed" and any(
        h.get("status") == "failed" and h.get("detail") == DROPPED for h in cmd.history
    )


def dropped(cmds: Iterable[Command], active: Collection[str]) -> list[Command]:
    """The commands the vehicle acknowledged (``accepted``, ``executing``) that, resuming,
    it does not name among those it carries out or has an ack to send for: nothing on the
    vehicle will finish them."""
    return [
        c
        for c in cmds
        if not c.final and rank(c.status) >= RANK["accepted"] and c.command_id not in active
    ]


def lost_with_lease(cmds: list[Command], holder: str) -> list[Command]:
    """The former holder's commands not yet acknowledged when a lease ends.

    They are cancelled so that one operator's orders never reach the vehicle
    under the next one's control; a ``stop`` is never among them.
    """
    return [
        c for c in cmds if c.issued_by == holder and not c.is_stop and c.status in UNACKNOWLEDGED
    ]
