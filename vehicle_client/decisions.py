"""The agent's decisions, apart from any I/O (sans-I/O core).

``Pilot`` takes what arrives (commands, ``abort`` lists, the adapter's task
reports, link loss and return) and answers with effects for the daemon to
carry out: acks to send, a task to start on the vehicle, a halt. It follows
API.md's command rules on the vehicle's side:

- ``stop`` before anything else in a batch, and it ends the active command;
- a command past ``expires_at`` (server clock) is refused (``rejected``);
- a ``command_id`` seen before is not carried out again; its last known
  status is acked again, in case the earlier ack was lost;
- ids in ``abort`` are stopped at once and never reported again;
- a type the vehicle lacks, or bad arguments, are ``rejected``;
- while the vehicle is under local control only ``stop`` is taken.

- a ``follow_path`` whose path does not hash to its ``path_hash`` (received
  in part, or altered) is never run: ``rejected`` with ``plan_mismatch``; one
  that does is ``accepted`` naming the hash of what the vehicle stored.

``LinkMonitor`` decides when the link-loss failsafe engages; the policy says
what the vehicle then does: nothing (``none``, an AUV that dives out of
contact), ``keep_station``, ``stop``, or ``return_home`` (the policy's home,
else where the vehicle first was in this run).
"""

from __future__ import annotations

from collections.abc import Iterable, MutableMapping
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from pydantic import ValidationError

from fleet_protocol import ARGS_MODELS, CommandObject, FailsafePolicy, FbAck, path_hash, route_of
from fleet_protocol.upper import ControlMode
from vehicle_client.sim.simulator import TaskReport

#: An ``executing`` ack is re-sent when progress moved at least this much.
PROGRESS_STEP = 0.05
#: Statuses after which a command is never acted on again.
FINAL = frozenset({"done", "failed", "rejected", "aborted"})


@dataclass(frozen=True)
class Execute:
    """Start a task on the vehicle (replacing whatever it was doing)."""

    kind: str
    args: dict[str, Any]
    command_id: str | None = None


@dataclass(frozen=True)
class Halt:
    """Drop the active task at once (thrust off) without a report."""


Effect = FbAck | Execute | Halt


def order_commands(commands: Iterable[CommandObject]) -> list[CommandObject]:
    """``stop`` first, then oldest first."""
    return sorted(commands, key=lambda c: (c.type != "stop", c.issued_at))


@dataclass
class Pilot:
    capabilities: frozenset[str]
    #: ``command_id`` -> last status acked; the daemon makes it persistent.
    seen: MutableMapping[str, str] = field(default_factory=dict)
    failsafe: FailsafePolicy = field(default_factory=FailsafePolicy)
    local_control: bool = False
    active_id: str | None = None
    active_kind: str | None = None
    in_failsafe: bool = False
    #: Where ``return_home`` goes when the policy names no home: the first position.
    home: tuple[float, float] | None = None
    _last_progress: float | None = None

    @property
    def control_mode(self) -> ControlMode:
        if self.local_control:
            return "local"
        if self.in_failsafe:
            return "failsafe"
        return "remote" if self.active_id is not None else "idle"

    # -- commands --------------------------------------------------------
    def on_commands(self, commands: Iterable[CommandObject], server_now: datetime) -> list[Effect]:
        effects: list[Effect] = []
        for command in order_commands(commands):
            effects.extend(self._one(command, server_now))
        return effects

    def _ack(self, command_id: str, status: str, **extra: Any) -> FbAck:
        self.seen[command_id] = status
        return FbAck(command_id=command_id, status=status, **extra)

    def _one(self, command: CommandObject, server_now: datetime) -> list[Effect]:
        cid = command.command_id
        previous = self.seen.get(cid)
        if previous is not None:
            if previous == "aborted" or (cid == self.active_id and previous == "executing"):
                return []  # aborted: never again; executing: progress acks follow
            return [FbAck(command_id=cid, status=previous)]
        if command.expires_at <= server_now:
            return [self._ack(cid, "rejected", detail="expired before the vehicle got it")]
        if command.type not in self.capabilities and command.type != "stop":
            return [self._ack(cid, "rejected", detail=f"this vehicle cannot {command.type}")]
        if self.local_control and command.type != "stop":
            return [self._ack(cid, "rejected", detail="vehicle_local_control")]
        try:
            ARGS_MODELS[command.type].model_validate(command.args)
        except ValidationError as exc:
            return [self._ack(cid, "rejected", detail=f"bad args: {exc.errors()[0]['msg']}")]
        stored_hash = None
        if command.type == "follow_path":
            stored_hash = path_hash(route_of(command.args))
            sent = command.args.get("path_hash")
            if sent is not None and sent != stored_hash:
                detail = f"plan_mismatch: the path received hashes to {stored_hash}, not {sent}"
                return [self._ack(cid, "rejected", detail=detail)]
        effects: list[Effect] = self._end_active(f"superseded by {command.type} {cid}")
        self.in_failsafe = False
        self.active_id, self.active_kind, self._last_progress = cid, command.type, None
        effects.append(self._ack(cid, "accepted", path_hash=stored_hash))
        effects.append(Execute(command.type, dict(command.args), cid))
        effects.append(self._ack(cid, "executing"))
        return effects

    def _end_active(self, detail: str) -> list[Effect]:
        if self.active_id is None:
            return []
        cid = self.active_id
        self.active_id = self.active_kind = None
        return [self._ack(cid, "failed", detail=detail)]

    # -- what the vehicle reports ----------------------------------------
    def on_report(self, report: TaskReport) -> list[Effect]:
        """The adapter's report on the active task."""
        cid = self.active_id
        if cid is None or report.kind != self.active_kind:
            return []
        if report.status == "executing":
            p = report.progress
            if p is None or (
                self._last_progress is not None and p - self._last_progress < PROGRESS_STEP
            ):
                return []
            self._last_progress = p
            return [self._ack(cid, "executing", progress=round(p, 3))]
        self.active_id = self.active_kind = None
        extra: dict[str, Any] = {"detail": report.detail}
        if report.progress is not None:
            extra["progress"] = round(report.progress, 3)
        return [self._ack(cid, report.status, **extra)]

    def on_abort(self, command_ids: Iterable[str]) -> list[Effect]:
        effects: list[Effect] = []
        for cid in command_ids:
            if self.seen.get(cid) == "aborted":
                continue
            self.seen[cid] = "aborted"
            if cid == self.active_id:
                self.active_id = self.active_kind = None
                effects.append(Halt())
        return effects

    # -- link ----------------------------------------------------------------
    def on_link_lost(self) -> list[Effect]:
        """The failsafe engages: the policy's action replaces the active command (with
        ``none`` the vehicle carries on as it was)."""
        action = self.failsafe.action
        if action == "none":
            return []
        effects = self._end_active(f"link lost: failsafe {action}")
        self.in_failsafe = True
        effects.append(self._failsafe_task(action))
        return effects

    def _failsafe_task(self, action: str) -> Execute:
        home = self.failsafe.home
        where = (home.lat, home.lon) if home is not None else self.home
        if action == "return_home" and where is not None:
            target = {"lat": where[0], "lon": where[1]}
            if "keep_station" in self.capabilities:  # there, and held there
                return Execute("keep_station", target)
            if "go_to" in self.capabilities:
                return Execute("go_to", target)
        if action in ("return_home", "keep_station") and "keep_station" in self.capabilities:
            return Execute("keep_station", {})
        return Execute("stop", {})

    def on_restart(self, unfinished: Iterable[str]) -> list[Effect]:
        """Commands a previous run of the agent accepted and never finished.

        Whatever the vehicle was doing stopped with that run, so they are
        reported ``failed``.
        """
        return [self._ack(cid, "failed", detail="agent restarted") for cid in unfinished]


@dataclass
class LinkMonitor:
    """Tells when the server has been silent for the failsafe policy's time.

    ``contact`` on every answer from the server; ``poll`` answers ``"lost"``
    once when the silence passes ``after_s`` and ``contact`` answers
    ``"restored"`` once when the server answers again after that.
    """

    after_s: float
    last_contact: float | None = None
    lost: bool = False
    lost_at: float | None = None

    def contact(self, now: float) -> str | None:
        self.last_contact = now
        if self.lost:
            self.lost = False
            return "restored"
        return None

    def poll(self, now: float) -> str | None:
        if self.lost or self.last_contact is None:
            return None
        if now - self.last_contact >= self.after_s:
            self.lost, self.lost_at = True, now
            return "lost"
        return None


def next_tick(due: float, now: float, period: float) -> float:
    """When the next sample is due, the one at ``due`` just taken at ``now``: a period on;
    but after a stall (the process stopped, the machine suspended) that left ticks behind,
    a period from now: the missed ticks are not taken back to back, which would make up
    samples of one instant and one place for a time nobody measured."""
    following = due + period
    return following if following > now - period else now + period
