"""Commands: submit (all or nothing), queue, cancel, expire; the server's own commands.

The store holds each instance's active commands (``commands_active``) and
every ended one (``commands``, inserted once); this replica keeps a
:class:`~server.services.lanes.Lane` per instance as a copy, caught up with
the store before it hands commands out, takes acks, cancels or expires them.
A command's end is recorded by whichever replica inserts it into the
history first (the store refuses a second insert of one command id). The
vehicle's side, handing commands out and taking their acks, is
:class:`~server.services.command_delivery.CommandDelivery`; the checks before
a submit is queued are :class:`~server.services.command_admission.Admission`'s.
"""

from __future__ import annotations

import secrets
from datetime import datetime
from typing import Any

from fleet_protocol import KeepStationArgs, SubmitControl
from fleet_protocol.admin import SERVER_ACTOR
from server.domain import arbitration
from server.domain import command_ends as ends
from server.domain import commands as life
from server.domain.access import Principal
from server.domain.clock import Clock
from server.domain.command_refusals import refused
from server.domain.commands import Command
from server.domain.events import InstanceFinished, LeaseEnded, StateWritten
from server.errors import NotFound, Unavailable
from server.metrics import Hops
from server.services.command_admission import Admission, ObstacleSource, ZoneSetSource
from server.services.command_delivery import CommandDelivery
from server.services.control import ControlService
from server.services.dead_letters import DeadLetters
from server.services.events import EventService
from server.services.instances import InstanceService, InstanceState
from server.services.lanes import Lane
from server.services.messagebus import MessageBus
from server.services.planning import Planner, Planning, vehicle_planner
from server.settings import Settings
from server.storage.commands import CommandsRepo

__all__ = ["CommandService"]

#: A command the server issues on its own (a vehicle held after a lease ends, a failsafe
#: on a zone breach) waits this long for the vehicle at most.
SYSTEM_TTL_S = 300
#: Who issues them.
SYSTEM = SERVER_ACTOR


#: The server's hold: where the vehicle is when it starts, in the default radius (the
#: arguments an operator's ``keep_station`` with none given is stored with).
HOLD_ARGS = KeepStationArgs().model_dump(exclude_none=True)


class CommandService(CommandDelivery):
    """The life of a command (see the module): the operators' side and the server's
    own commands, on :class:`~server.services.command_delivery.CommandDelivery` (the
    vehicle's side) and the lanes of
    :class:`~server.services.command_lanes.CommandLanes`."""

    def __init__(
        self,
        settings: Settings,
        repo: CommandsRepo,
        instances: InstanceService,
        control: ControlService,
        events: EventService,
        messages: MessageBus,
        dead_letters: DeadLetters,
        obstacles: ObstacleSource,
        zones: ZoneSetSource,
        clock: Clock,
        planner: Planner | None = None,
        hops: Hops | None = None,
    ) -> None:
        super().__init__(repo, events, messages, clock)
        self.settings = settings
        #: Where the command hops are measured (``/metrics``); None: nowhere.
        self.hops = hops
        self.instances = instances
        self.control = control
        self.dead_letters = dead_letters
        self.zones = zones
        self._seq = 0
        self.admission = Admission(
            instances,
            control,
            Planning(
                planner or vehicle_planner(settings.safety_radius_m),
                settings.plan_timeout_s,
                settings.plan_workers,
            ),
            obstacles,
            zones,
            settings.separation_m,
            self._lanes,
            clock,
        )

    async def load(self) -> None:
        """Take the active commands of a former run up again."""
        await self.repo.ensure_indexes()
        for doc in await self.repo.all_active():
            cmd = Command.from_doc(doc)
            self._lane(cmd.instance_id).add(cmd)
            self._seq = max(self._seq, cmd.seq)

    # ---- operators ------------------------------------------------------------
    async def submit(self, principal: Principal, body: SubmitControl) -> dict[str, Any]:
        """The commands queued, one per target, all or nothing; ``warnings``: what the
        operator may not have meant (several vehicles sent to meet at one point)."""
        now = self.clock()
        admission = self.admission
        targets, refusals = await admission.targets(principal, body.instance_ids)
        # The queue bound and a stop's supersedes see what every replica queued.
        await self._sync_many([state.instance_id for _, state in targets])
        refusals += admission.check_all(principal, targets, body.command)
        args_by_instance: dict[str, dict[str, Any]] = {}
        zones_version = None
        if not refusals:
            args_by_instance, refusals, zones_version = await admission.args_for(
                targets, body.command
            )
            if body.command.type == "follow_path":  # planning yields: check again
                refusals += admission.check_all(principal, targets, body.command)
        if refusals:
            raise refused(refusals, len(body.instance_ids))
        made = []
        for _, state in targets:
            self._seq += 1
            made.append(
                life.new_command(
                    command_id="c-" + secrets.token_hex(8),
                    instance_id=state.instance_id,
                    vehicle_id=state.vehicle_id,
                    type=body.command.type,
                    args=args_by_instance[state.instance_id],
                    issued_by=principal.name,
                    now=now,
                    ttl_s=body.ttl_s,
                    seq=self._seq,
                    max_drift_m=body.command.max_drift_m,
                    position=state.position,
                    by_manager=arbitration.may_grant(principal, state.vehicle_id),
                    zones_version=None if body.command.type == "stop" else zones_version,
                )
            )
        superseded: list[Command] = []
        for cmd in made:  # memory first: a poll from now on sees the whole submit
            lane = self._lane(cmd.instance_id)
            lane.add(cmd)
            if cmd.is_stop:
                others = [c for c in lane.active.values() if c is not cmd]
                superseded += ends.supersede(others, cmd, now)
        if made:
            await self.repo.insert_active([cmd.to_doc() for cmd in made])
        for cmd in made:
            self.messages.emit_now(StateWritten(cmd.instance_id, "commands"))
            self._ready(self._lane(cmd.instance_id))
            await self._audit(cmd, principal, args=cmd.args)
        for gone in superseded:
            await self._finished(gone)
        queued = [
            {"instance_id": c.instance_id, "command_id": c.command_id, "status": "queued"}
            for c in made
        ]
        expires = made[0].expires_at if made else now
        warnings = await self.admission.warnings(targets, body.command, args_by_instance, expires)
        return {"commands": queued, "warnings": warnings}

    async def cancel(self, principal: Principal, command_id: str) -> Command:
        cmd = await self._find(command_id)
        if not principal.can_see(cmd.vehicle_id):
            raise NotFound(f"no command {command_id}")  # as an unknown one (docs/security.md)
        if cmd.final:
            return cmd
        lease = await self.control.current(cmd.instance_id)
        ends.check_cancel(
            cmd,
            principal.name,
            holds=arbitration.holds(lease, principal.name, self.clock()),
            manages=arbitration.may_grant(principal, cmd.vehicle_id),
        )
        if ends.cancel(cmd, self.clock(), f"by {principal.name}"):
            await self._finished(cmd, actor=principal)
        return cmd

    async def get(self, principal: Principal, command_id: str) -> Command:
        cmd = await self._read(command_id)
        if cmd is None or not principal.can_see(cmd.vehicle_id):
            raise NotFound(f"no command {command_id}")  # unknown, or not for this caller
        return cmd

    async def recent(self, principal: Principal, instance_id: str) -> tuple[str, list[Command]]:
        """The instance's control mode and its active and recent commands, newest first."""
        state = await self.instances.for_viewer(principal, instance_id)
        limit = self.settings.command_history_limit
        docs = await self.repo.active_for(state.instance_id)
        seen = {d["command_id"] for d in docs}
        docs += [
            d
            for d in await self.repo.recent_finished(state.instance_id, limit)
            if d["command_id"] not in seen
        ]
        recent = [Command.from_doc(d) for d in docs]
        recent.sort(key=lambda c: (c.issued_at, c.seq), reverse=True)
        return state.control_mode, recent[:limit]

    # ---- background and handlers ------------------------------------------------
    async def sweep(self, now: datetime | None = None) -> None:
        """Expire what is past ``expires_at``; wake the lanes with a redelivery due."""
        now = now or self.clock()
        timeout = self.settings.ack_timeout_s
        for lane in [lane for lane in self._lanes.values() if lane.active]:  # few, most ticks
            try:
                await self._sweep_lane(lane, now, timeout)
            except Unavailable as exc:
                self.dead_letters.failed("commands", exc)
                return
            except Exception as exc:
                await self.dead_letters.set_aside("commands", lane.instance_id, exc, lane.active)
                self._lanes.pop(lane.instance_id, None)  # read again from the store when needed

    async def _sweep_lane(self, lane: Lane, now: datetime, ack_timeout_s: float) -> None:
        if any(life.expires_now(c, now) for c in lane.active.values()):
            await self._sync(lane.instance_id)  # acknowledged on another replica?
        due = False
        for cmd in list(lane.active.values()):
            if life.expire_if_due(cmd, now):
                await self._finished(cmd)
            elif life.due_for_delivery(cmd, now, ack_timeout_s):
                due = True
        if due:
            self._ready(lane)

    async def drop_finished_before(self, before: datetime) -> int:
        return await self.repo.drop_finished_before(before)

    async def on_lease_end(self, event: LeaseEnded) -> None:
        """The former holder's commands not yet acknowledged are cancelled, and the vehicle
        is told to hold station where it is (what it was doing for the holder ends)."""
        lease = event.lease
        lane = await self._sync(lease.instance_id)
        now = self.clock()
        detail = "instance_finished" if event.reason == "instance_finished" else "lease_ended"
        for cmd in ends.lost_with_lease(list(lane.active.values()), lease.holder):
            ends.cancel(cmd, now, detail)
            await self._finished(cmd)
        if event.reason == "instance_finished":
            return
        held = await self.hold(
            lease.instance_id, f"control of {lease.holder} ended: {event.reason}"
        )
        await self.events.record(
            "hold_station",
            vehicle_id=lease.vehicle_id,
            instance_id=lease.instance_id,
            actor=SYSTEM,
            data={
                "holder": lease.holder,
                "reason": event.reason,
                "command_id": held.command_id if held is not None else None,
                "type": held.type if held is not None else None,
                # a stop sent before, still under way, holds it (no hold was sent)
                **({"stop_kept": True} if held is not None and held.issued_by != SYSTEM else {}),
            },
        )

    async def hold(self, instance_id: str, why: str) -> Command | None:
        """Tell the vehicle to hold station where it is (``stop`` if it cannot keep
        station); None when it is finished or under local control (only its crew acts).
        A stop still under way is what holds it: it is kept, and no hold is sent (the
        hold, newer, would replace the stop on the vehicle)."""
        state = await self.instances.find(instance_id)
        if state.finished or state.control_mode == "local":
            return None
        lane = await self._sync(instance_id)
        stop = next((c for c in life.queue_order(list(lane.active.values())) if c.is_stop), None)
        if stop is not None:  # it brings the vehicle to rest: a hold would replace it there
            return stop
        if "keep_station" in state.capabilities:  # with its radius, as an operator's has it
            return await self.system_command(state, "keep_station", HOLD_ARGS, why)
        return await self.system_command(state, "stop", {}, why)

    async def system_command(
        self, state: InstanceState, kind: str, args: dict[str, Any], why: str
    ) -> Command:
        """A command the server issues on its own (no lease needed), queued as any other;
        a ``stop`` supersedes what waits. ``why`` goes into its first history entry."""
        now = self.clock()
        self._seq += 1
        cmd = life.new_command(
            command_id="c-" + secrets.token_hex(8),
            instance_id=state.instance_id,
            vehicle_id=state.vehicle_id,
            type=kind,
            args=dict(args),
            issued_by=SYSTEM,
            now=now,
            ttl_s=SYSTEM_TTL_S,
            seq=self._seq,
            position=state.position,
            by_manager=True,
        )
        if cmd.history:
            cmd.history[-1]["detail"] = why
        await self._sync(state.instance_id)
        lane = self._lane(state.instance_id)
        lane.add(cmd)
        others = [c for c in lane.active.values() if c is not cmd]
        if cmd.is_stop:
            superseded = ends.supersede(others, cmd, now)
        elif kind == "keep_station" and "lat" not in args:  # a hold where it is
            superseded = ends.supersede_holds(others, cmd, now)
        else:
            superseded = []
        await self.repo.insert_active([cmd.to_doc()])
        self.messages.emit_now(StateWritten(cmd.instance_id, "commands"))
        self._ready(lane)
        await self._audit(cmd, None, args=cmd.args, detail=why)
        for gone in superseded:
            await self._finished(gone)
        return cmd

    async def on_instance_finished(self, event: InstanceFinished) -> None:
        lane = await self._sync(event.instance_id)
        now = self.clock()
        for cmd in list(lane.active.values()):
            ends.cancel(cmd, now, "instance_finished")
            await self._finished(cmd)
        lane.wake()
        self._lanes.pop(event.instance_id, None)
