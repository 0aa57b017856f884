"""Command life cycle: statuses, acks, queue order, expiry, redelivery, drift. Pure.

``queued -> delivered -> accepted -> executing -> done``, or one of the final
``rejected``, ``failed``, ``expired``, ``cancelled``. Acks move forward only;
a backward ack is written into the history and otherwise ignored. An ack
for a command already final is recorded and leaves the status alone.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timedelta
from enum import Enum
from typing import Any

from fleet_protocol import FINAL_STATUSES
from server.domain.geo import haversine_m
from server.errors import CapabilityMissing

#: Position of each status along the life cycle; every final status ranks last.
RANK = {"queued": 0, "delivered": 1, "accepted": 2, "executing": 3}
FINAL_RANK = 4
#: Final statuses an ack cannot undo and that the vehicle must not carry out.
ABORT_STATUSES = frozenset({"expired", "cancelled"})
#: Statuses that count as "acknowledged" for expiry: past these, a command never expires.
UNACKNOWLEDGED = frozenset({"queued", "delivered"})


def rank(status: str) -> int:
    return FINAL_RANK if status in FINAL_STATUSES else RANK[status]


@dataclass
class Command:
    """One command to one instance, as the server keeps it."""

    command_id: str
    instance_id: str
    vehicle_id: str
    type: str
    args: dict[str, Any]
    issued_by: str
    issued_at: datetime
    expires_at: datetime
    seq: int  # issue order on this server, ties issued_at
    max_drift_m: float | None = None
    issued_from: tuple[float, float] | None = None  # (lat, lon) at issue time
    status: str = "queued"
    progress: float | None = None
    history: list[dict[str, Any]] = field(default_factory=list)
    delivered_at: datetime | None = None
    deliveries: int = 0
    #: Issued by a manager of the vehicle or an admin: a stop of theirs is theirs to undo.
    by_manager: bool = False
    #: The version of the zones the command was checked against (None: not checked).
    zones_version: int | None = None

    @property
    def final(self) -> bool:
        return self.status in FINAL_STATUSES

    @property
    def is_stop(self) -> bool:
        return self.type == "stop"

    def note(self, status: str, at: datetime, detail: str | None = None) -> None:
        self.history.append({"status": status, "at": at, "detail": detail})

    def move(self, status: str, at: datetime, detail: str | None = None) -> None:
        self.status = status
        self.note(status, at, detail)

    def catch_up(self, stored: Command) -> bool:
        """Take the store's copy when it has moved further (another replica moved it).

        History only grows, so the longer history is the later state; whether it moved.
        """
        if len(stored.history) <= len(self.history) and not stored.final:
            return False
        self.status, self.progress = stored.status, stored.progress
        self.history = [dict(h) for h in stored.history]
        self.delivered_at, self.deliveries = stored.delivered_at, stored.deliveries
        return True

    def wire(self) -> dict[str, Any]:
        """The contract's command object (times as datetimes; the wire model formats them)."""
        return {
            "command_id": self.command_id,
            "instance_id": self.instance_id,
            "vehicle_id": self.vehicle_id,
            "type": self.type,
            "args": self.args,
            "max_drift_m": self.max_drift_m,
            "status": self.status,
            "issued_by": self.issued_by,
            "issued_at": self.issued_at,
            "expires_at": self.expires_at,
            "progress": self.progress,
            "history": [dict(h) for h in self.history],
        }

    def to_doc(self) -> dict[str, Any]:
        doc = self.wire()
        doc.update(
            seq=self.seq,
            issued_from=list(self.issued_from) if self.issued_from else None,
            delivered_at=self.delivered_at,
            deliveries=self.deliveries,
            by_manager=self.by_manager,
            zones_version=self.zones_version,
        )
        return doc

    @classmethod
    def from_doc(cls, doc: dict[str, Any]) -> Command:
        origin = doc.get("issued_from")
        return cls(
            command_id=doc["command_id"],
            instance_id=doc["instance_id"],
            vehicle_id=doc.get("vehicle_id") or "",
            type=doc["type"],
            args=doc.get("args") or {},
            issued_by=doc["issued_by"],
            issued_at=doc["issued_at"],
            expires_at=doc["expires_at"],
            seq=int(doc.get("seq") or 0),
            max_drift_m=doc.get("max_drift_m"),
            issued_from=(float(origin[0]), float(origin[1])) if origin else None,
            status=doc["status"],
            progress=doc.get("progress"),
            history=[dict(h) for h in doc.get("history") or []],
            delivered_at=doc.get("delivered_at"),
            deliveries=int(doc.get("deliveries") or 0),
            by_manager=bool(doc.get("by_manager")),
            zones_version=doc.get("zones_version"),
        )


def new_command(
    *,
    command_id: str,
    instance_id: str,
    vehicle_id: str,
    type: str,
    args: dict[str, Any],
    issued_by: str,
    now: datetime,
    ttl_s: float,
    seq: int,
    max_drift_m: float | None = None,
    position: dict[str, Any] | None = None,
    by_manager: bool = False,
    zones_version: int | None = None,
) -> Command:
    cmd = Command(
        command_id=command_id,
        instance_id=instance_id,
        vehicle_id=vehicle_id,
        type=type,
        args=args,
        issued_by=issued_by,
        issued_at=now,
        expires_at=now + timedelta(seconds=ttl_s),
        seq=seq,
        max_drift_m=max_drift_m,
        issued_from=(float(position["lat"]), float(position["lon"])) if position else None,
        by_manager=by_manager,
        zones_version=zones_version,
    )
    cmd.note("queued", now)
    return cmd


def check_capability(command_type: str, capabilities: list[str]) -> None:
    """Every vehicle can stop; anything else must be in its capabilities."""
    if command_type != "stop" and command_type not in capabilities:
        raise CapabilityMissing(
            f"the vehicle cannot execute {command_type}",
            details=[{"field": "command.type", "message": f"not in capabilities {capabilities}"}],
        )


# ---- acks -----------------------------------------------------------------


class AckOutcome(Enum):
    APPLIED = "applied"  # the status moved forward (or progress changed)
    BACKWARD = "backward"  # recorded, ignored
    LATE = "late"  # the command was already final: recorded, status untouched


def apply_ack(
    cmd: Command,
    status: str,
    now: datetime,
    *,
    progress: float | None = None,
    detail: str | None = None,
) -> AckOutcome:
    if cmd.final:
        _note_ignored(cmd, status, now, _join("ignored, already " + cmd.status, detail))
        return AckOutcome.LATE
    if rank(status) < rank(cmd.status):
        _note_ignored(cmd, status, now, _join("ignored, backward from " + cmd.status, detail))
        return AckOutcome.BACKWARD
    if status == "done":
        cmd.progress = 1.0  # whatever the ack said: done is all of it
    elif progress is not None:
        # Never backwards: a late report of less (acks overtaken on the way) is kept out.
        cmd.progress = max(progress, cmd.progress or 0.0)
    if status == cmd.status:
        return AckOutcome.APPLIED  # a progress report: no new history entry
    cmd.move(status, now, detail)
    return AckOutcome.APPLIED


#: Acks a command's history records as ignored, at most: a vehicle that repeats its last
#: ack (or a token that floods them) cannot grow a command without bound.
IGNORED_KEPT = 16


def _note_ignored(cmd: Command, status: str, now: datetime, detail: str) -> None:
    """Record an ignored ack, unless it repeats the entry before it or the command has
    :data:`IGNORED_KEPT` of them already (the ack is still answered: ``abort``)."""
    entry = f"ack:{status}"
    last = cmd.history[-1] if cmd.history else None
    if last is not None and (last["status"], last.get("detail")) == (entry, detail):
        return
    ignored = sum(1 for h in cmd.history if str(h.get("detail") or "").startswith("ignored"))
    if ignored < IGNORED_KEPT:
        cmd.note(entry, now, detail)


#: How an agent ends the mission a newer command replaced: ``failed``, this detail and
#: the newer command (the contract's acks have no status for it).
AGENT_SUPERSEDED = "superseded by "
#: The detail of a command a newer one replaced on the vehicle (``cancelled``); a stop
#: that cancels what waits says ``superseded_by_stop``.
SUPERSEDED_BY = "superseded_by "


def superseded(status: str, detail: str | None) -> tuple[str, str | None]:
    """A mission the vehicle ended because a newer command replaced it did not fail: it is
    ``cancelled`` with ``superseded_by <type> <command_id>``, shown as superseded."""
    if status == "failed" and detail is not None and detail.startswith(AGENT_SUPERSEDED):
        return "cancelled", SUPERSEDED_BY + detail[len(AGENT_SUPERSEDED) :]
    return status, detail


def check_plan(
    cmd: Command, status: str, path_hash: str | None, detail: str | None
) -> tuple[str, str | None]:
    """A ``follow_path`` the vehicle accepts must be the path sent: when the vehicle names
    the hash of what it stored and that is not the command's, the command fails
    (``plan_mismatch``) and is never run. A vehicle that names no hash is taken at its
    word (one written before hashes were)."""
    expected = cmd.args.get("path_hash")
    if (
        cmd.type != "follow_path"
        or status not in ("accepted", "executing")
        or path_hash is None
        or expected is None
        or path_hash == expected
    ):
        return status, detail
    return "failed", f"plan_mismatch: the vehicle stored {path_hash}, the path sent is {expected}"


def _join(head: str, tail: str | None) -> str:
    return f"{head}: {tail}" if tail else head


# ---- expiry, drift, delivery ------------------------------------------------


def expires_now(cmd: Command, now: datetime) -> bool:
    """Not acknowledged by ``expires_at``: to be expired, handed out or not."""
    return cmd.status in UNACKNOWLEDGED and now >= cmd.expires_at


def expire_if_due(cmd: Command, now: datetime) -> bool:
    """A command not acknowledged by ``expires_at`` is expired, handed out or not."""
    if expires_now(cmd, now):
        cmd.move("expired", now)
        return True
    return False


def drifted(cmd: Command, position: dict[str, Any] | None) -> bool:
    """Whether the vehicle is farther than ``max_drift_m`` from where it was at issue time."""
    if cmd.max_drift_m is None or cmd.issued_from is None or position is None:
        return False
    lat0, lon0 = cmd.issued_from
    return haversine_m(lat0, lon0, float(position["lat"]), float(position["lon"])) > cmd.max_drift_m


def needs_fresh_position(cmd: Command) -> bool:
    """A queued command whose drift is to be judged: it waits for a current position."""
    return cmd.status == "queued" and cmd.max_drift_m is not None and cmd.issued_from is not None


def position_is_current(position: dict[str, Any] | None, now: datetime, within_s: float) -> bool:
    """Whether the latest position is recent enough to judge a drift by (its own time at
    most ``within_s`` before ``now``). None, no position: there is no drift to judge."""
    if position is None:
        return True
    ts = position["ts"]
    if ts.tzinfo is None:
        ts = ts.replace(tzinfo=now.tzinfo)
    return (now - ts).total_seconds() <= within_s


def due_for_delivery(cmd: Command, now: datetime, ack_timeout_s: float) -> bool:
    """Queued, or handed out and not acknowledged within ``ack_timeout_s``."""
    if cmd.status == "queued":
        return True
    if cmd.status == "delivered" and cmd.delivered_at is not None:
        return (now - cmd.delivered_at).total_seconds() >= ack_timeout_s
    return False


def next_redelivery(cmd: Command, ack_timeout_s: float) -> datetime | None:
    if cmd.status == "delivered" and cmd.delivered_at is not None:
        return cmd.delivered_at + timedelta(seconds=ack_timeout_s)
    return None


def mark_delivered(cmd: Command, now: datetime) -> None:
    redelivery = cmd.deliveries > 0
    cmd.deliveries += 1
    cmd.delivered_at = now
    if redelivery:
        cmd.note("delivered", now, f"redelivery {cmd.deliveries - 1}")
    else:
        cmd.move("delivered", now)


def queue_order(cmds: list[Command]) -> list[Command]:
    """``stop`` first, then oldest first."""
    return sorted(cmds, key=lambda c: (not c.is_stop, c.issued_at, c.seq))


def handout(
    cmds: list[Command],
    now: datetime,
    *,
    ack_timeout_s: float,
    position: dict[str, Any] | None,
    position_current: bool = True,
    held: list[Command] | None = None,
) -> tuple[list[Command], list[Command]]:
    """What to hand out now, in order; and what expired on the way (expiry, drift).

    Marks the handed-out commands delivered. An expired command is never handed out.
    A command with ``max_drift_m`` is not handed out while the position is not current
    (``position_current`` False: a vehicle back from a link loss whose positions of the
    meantime have not come yet): it goes into ``held``, and waits for one that is.
    """
    out: list[Command] = []
    ended: list[Command] = []
    for cmd in queue_order(cmds):
        if cmd.final:
            continue
        if expire_if_due(cmd, now):
            ended.append(cmd)
            continue
        if not due_for_delivery(cmd, now, ack_timeout_s):
            continue
        if not position_current and needs_fresh_position(cmd):
            if held is not None:
                held.append(cmd)
            continue
        if cmd.status == "queued" and drifted(cmd, position):
            cmd.move("expired", now, "drifted")
            ended.append(cmd)
            continue
        mark_delivered(cmd, now)
        out.append(cmd)
    return out, ended
