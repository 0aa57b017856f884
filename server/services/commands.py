"""Commands: submit (all or nothing), queue, hand out, acknowledge, cancel, expire.

Hot state (each instance's active commands) lives in a :class:`Lane` and in
the small ``commands_active`` collection; a command that ends is inserted
once into the history. Delivery has one path, :meth:`CommandService.take`,
for long polls and vehicle sockets alike: sockets register in
``ready_listeners``, are told an instance has something to hand out (on
submit, when a redelivery falls due), then call :meth:`take`.

On several replicas the lanes are a cache of the store: a replica reads an
instance's active commands back before it hands them out, cancels them or
takes acks, records a command's end only if it took it out of
``commands_active``, and announces what it wrote (services/replicas.py).
"""

from __future__ import annotations

import asyncio
import secrets
from collections import Counter
from collections.abc import Callable, KeysView
from datetime import datetime
from typing import Any

from fleet_protocol import SubmitControl
from server.domain import arbitration
from server.domain import commands as life
from server.domain.access import Principal
from server.domain.commands import AckOutcome, Command
from server.errors import ControlNotHeld, Forbidden, NotFound, RateLimited
from server.services.command_admission import MAX_ACTIVE_PER_INSTANCE, Admission
from server.services.control import ControlService
from server.services.events import EventService
from server.services.instances import InstanceService, InstanceState
from server.services.lanes import Lane, StoredLanes
from server.services.planning import Planner, vehicle_planner
from server.services.replicas import Announce, no_announce
from server.settings import Settings
from server.storage.commands import CommandsRepo

Clock = Callable[[], datetime]
ReadyListener = Callable[[str], None]

__all__ = ["MAX_ACTIVE_PER_INSTANCE", "CommandService"]


class CommandService:
    def __init__(
        self,
        settings: Settings,
        repo: CommandsRepo,
        instances: InstanceService,
        control: ControlService,
        events: EventService,
        clock: Clock,
        planner: Planner | None = None,
    ) -> None:
        self.settings = settings
        self.repo = repo
        self.instances = instances
        self.control = control
        self.events = events
        self.clock = clock
        self.planner = planner or vehicle_planner(settings.safety_radius_m)
        self._lanes: dict[str, Lane] = {}
        self._seq = 0
        #: Called with an instance id that has commands to hand out (vehicle sockets).
        self.ready_listeners: list[ReadyListener] = []
        #: Several replicas: the store is the truth (see server/services/replicas.py).
        self.shared = settings.shared_state
        self.announce: Announce = no_announce
        self.admission = Admission(instances, control, self.planner, self._lanes, clock)
        self.stored = StoredLanes(repo, self._lanes, self._lane)
        self._sync = self.stored.sync
        control.lease_end_listeners.append(self._on_lease_end)
        instances.finish_hooks.append(self._on_finish)

    async def load(self) -> None:
        """Take the active commands of a former run up again."""
        await self.repo.ensure_indexes()
        for doc in await self.repo.all_active():
            cmd = Command.from_doc(doc)
            self._lane(cmd.instance_id).add(cmd)
            self._seq = max(self._seq, cmd.seq)

    # ---- operators ------------------------------------------------------------
    async def submit(self, principal: Principal, body: SubmitControl) -> list[dict[str, Any]]:
        now = self.clock()
        admission = self.admission
        targets, refusals = await admission.targets(principal, body.instance_ids)
        refusals += admission.check_all(principal, targets, body.command)
        args_by_instance: dict[str, dict[str, Any]] = {}
        if not refusals:
            args_by_instance, refusals = await admission.args_for(targets, body.command)
            if body.command.type == "follow_path":  # planning yields: check again
                refusals += admission.check_all(principal, targets, body.command)
        if refusals:
            raise life.refused(refusals, len(body.instance_ids))
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
                )
            )
        if self.shared and body.command.type == "stop":  # what it supersedes, wherever queued
            for cmd in made:
                await self._sync(cmd.instance_id)
        superseded: list[Command] = []
        for cmd in made:  # memory first: a poll from now on sees the whole submit
            lane = self._lane(cmd.instance_id)
            lane.add(cmd)
            if cmd.is_stop:
                others = [c for c in lane.active.values() if c is not cmd]
                superseded += life.supersede(others, cmd, now)
        if made:
            await self.repo.insert_active([cmd.to_doc() for cmd in made])
        for cmd in made:
            self.announce(cmd.instance_id, "commands")
            self._ready(self._lane(cmd.instance_id))
            await self._audit(cmd, principal, args=cmd.args)
        for gone in superseded:
            await self._finished(gone)
        return [
            {"instance_id": c.instance_id, "command_id": c.command_id, "status": "queued"}
            for c in made
        ]

    async def cancel(self, principal: Principal, command_id: str) -> Command:
        cmd = await self._find(command_id)
        if not principal.can_see(cmd.vehicle_id):
            raise Forbidden(f"no access to vehicle {cmd.vehicle_id}")
        if cmd.final:
            return cmd
        lease = self.control.lease(cmd.instance_id)
        if not (
            cmd.issued_by == principal.name
            or arbitration.holds(lease, principal.name, self.clock())
            or arbitration.may_grant(principal, cmd.vehicle_id)
        ):
            raise ControlNotHeld("only its issuer, the control holder or a manager cancels it")
        if life.cancel(cmd, self.clock(), f"by {principal.name}"):
            await self._finished(cmd, actor=principal)
        return cmd

    async def get(self, principal: Principal, command_id: str) -> Command:
        cmd = await self._find(command_id, read_only=True)
        if not principal.can_see(cmd.vehicle_id):
            raise Forbidden(f"no access to vehicle {cmd.vehicle_id}")
        return cmd

    async def recent(self, principal: Principal, instance_id: str) -> tuple[str, list[Command]]:
        """The instance's control mode and its recent commands, newest first."""
        state = await self.instances.for_viewer(principal, instance_id)
        limit = self.settings.command_history_limit
        if self.shared:
            return state.control_mode, await self.stored.recent(state.instance_id, limit)
        lane = self._lanes.get(state.instance_id)
        mine = [*lane.active.values(), *lane.recent] if lane is not None else []
        if lane is None or not lane.history_loaded:
            seen = {c.command_id for c in mine}
            stored = [
                Command.from_doc(doc)
                for doc in await self.repo.recent_finished(state.instance_id, limit)
                if doc["command_id"] not in seen
            ]
            mine += stored
            if lane is not None:
                lane.remember(stored)
        mine.sort(key=lambda c: (c.issued_at, c.seq), reverse=True)
        return state.control_mode, mine[:limit]

    # ---- vehicles -------------------------------------------------------------
    async def get_control(
        self, principal: Principal, instance_id: str, wait_s: float
    ) -> list[Command]:
        """Hand out what is due, waiting up to ``wait_s`` for something to come."""
        state = await self.instances.for_vehicle_caller(principal, instance_id)
        lane = self._lane(state.instance_id)
        if wait_s > 0 and lane.polls >= self.settings.long_poll_max:
            raise RateLimited(
                f"{lane.polls} long polls are already open for this vehicle", retry_after_s=1
            )
        self.instances.touch(state)
        loop = asyncio.get_running_loop()
        deadline = loop.time() + wait_s
        lane.polls += 1
        state.polling += 1
        try:
            while True:
                woken = lane.waiter()
                out = await self.take(state)
                remaining = deadline - loop.time()
                if out or remaining <= 0 or state.finished:
                    return out
                try:
                    await asyncio.wait_for(woken.wait(), remaining)
                except TimeoutError:
                    pass
        finally:
            lane.polls -= 1
            state.polling -= 1
            self.instances.touch(state)

    async def take(self, state: InstanceState) -> list[Command]:
        """The commands to hand out now, in order (``stop`` first), marked delivered."""
        if state.finished:
            return []
        lane = await self._sync(state.instance_id) if self.shared else self._lane(state.instance_id)
        out, ended = life.handout(
            list(lane.active.values()),
            self.clock(),
            ack_timeout_s=self.settings.ack_timeout_s,
            position=state.position,
        )
        for cmd in ended:
            await self._finished(cmd)
        for cmd in out:
            await self.repo.save_active(cmd.to_doc())
        if out:
            self.announce(state.instance_id, "commands")
        return out

    async def acknowledge(
        self, principal: Principal, instance_id: str, control_mode: str | None, acks: list[Any]
    ) -> list[str]:
        """Apply the vehicle's acks; returns the ``abort`` list."""
        state = await self.instances.for_vehicle_caller(principal, instance_id)
        self.instances.touch(state)
        if self.instances.set_control_mode(state, control_mode):
            await self.events.record(  # failsafe and local control matter to the operators
                "control_mode",
                vehicle_id=state.vehicle_id,
                instance_id=state.instance_id,
                actor=principal,
                data={"control_mode": control_mode},
            )
            await self.instances.save_now(state)
        shared = self.shared and bool(acks)
        lane = await self._sync(state.instance_id) if shared else self._lane(state.instance_id)
        now = self.clock()
        abort: list[str] = []
        for ack in acks:
            cmd = lane.get(ack.command_id) or await self._stored(ack.command_id, state)
            if cmd is None:
                abort.append(ack.command_id)  # unknown here: never to be carried out
                continue
            outcome = life.apply_ack(cmd, ack.status, now, progress=ack.progress, detail=ack.detail)
            if outcome is AckOutcome.LATE:
                if cmd.status in life.ABORT_STATUSES:
                    abort.append(cmd.command_id)
            elif cmd.final:
                await self._finished(cmd)
            elif cmd.command_id in lane.active:
                await self.repo.save_active(cmd.to_doc())
        if shared:
            self.announce(state.instance_id, "commands")
        abort.extend(lane.take_aborts())
        return list(dict.fromkeys(abort))

    def counts_by_status(self) -> dict[str, int]:
        """Active commands by status (for /metrics)."""
        return dict(
            Counter(c.status for lane in self._lanes.values() for c in lane.active.values())
        )

    # ---- background and hooks ----------------------------------------------------
    async def sweep(self, now: datetime | None = None) -> None:
        """Expire what is past ``expires_at``; wake the lanes with a redelivery due."""
        now = now or self.clock()
        timeout = self.settings.ack_timeout_s
        for lane in list(self._lanes.values()):
            if not lane.active:
                continue  # most vehicles, most ticks
            due = False
            if self.shared and any(life.expires_now(c, now) for c in lane.active.values()):
                await self._sync(lane.instance_id)  # acknowledged on another replica?
            for cmd in list(lane.active.values()):
                if life.expire_if_due(cmd, now):
                    await self._finished(cmd)
                elif life.due_for_delivery(cmd, now, timeout):
                    due = True
            if due:
                self._ready(lane)

    async def drop_finished_before(self, before: datetime) -> int:
        return await self.repo.drop_finished_before(before)

    async def _on_lease_end(self, lease: arbitration.Lease, reason: str) -> None:
        if self.shared:
            await self._sync(lease.instance_id)
        if (lane := self._lanes.get(lease.instance_id)) is None:
            return
        now = self.clock()
        detail = "instance_finished" if reason == "instance_finished" else "lease_ended"
        for cmd in life.lost_with_lease(list(lane.active.values()), lease.holder):
            life.cancel(cmd, now, detail)
            await self._finished(cmd)

    async def _on_finish(self, state: InstanceState, principal: Principal | None) -> None:
        if self.shared:
            await self._sync(state.instance_id)
        if (lane := self._lanes.get(state.instance_id)) is None:
            return
        now = self.clock()
        for cmd in list(lane.active.values()):
            life.cancel(cmd, now, "instance_finished")
            await self._finished(cmd)
        lane.wake()
        del self._lanes[state.instance_id]

    # ---- several replicas -----------------------------------------------------
    async def refresh(self, instance_id: str) -> None:
        """Another replica moved the instance's commands: catch up. Commands new here are
        handed out (to this replica's socket, or through the nudge), the long polls woken."""
        if (lane := self._lanes.get(instance_id)) is None:
            return
        known = set(lane.active)
        await self._sync(instance_id)
        if set(lane.active) - known:
            self._ready(lane)
        else:
            lane.wake()

    @property
    def lane_ids(self) -> KeysView[str]:
        return self._lanes.keys()

    def forget(self, instance_id: str) -> None:
        """The instance finished on another replica (which ended its commands)."""
        if (lane := self._lanes.pop(instance_id, None)) is not None:
            lane.wake()

    # ---- internals ------------------------------------------------------------
    def _lane(self, instance_id: str) -> Lane:
        if (lane := self._lanes.get(instance_id)) is None:
            lane = self._lanes[instance_id] = Lane(instance_id, self.settings.command_history_limit)
        return lane

    def _ready(self, lane: Lane) -> None:
        lane.wake()
        for listener in self.ready_listeners:
            listener(lane.instance_id)

    async def _find(self, command_id: str, *, read_only: bool = False) -> Command:
        if self.shared:
            return await self.stored.find(command_id, read_only)
        for lane in self._lanes.values():
            if (cmd := lane.get(command_id)) is not None:
                return cmd
        if (cmd := await self._stored(command_id)) is None:
            raise NotFound(f"no command {command_id}")
        return cmd

    async def _stored(self, command_id: str, state: InstanceState | None = None) -> Command | None:
        """A command from the store (of ``state``'s instance, when given)."""
        doc = await self.repo.get(command_id)
        if doc is None or (state is not None and doc["instance_id"] != state.instance_id):
            return None
        return Command.from_doc(doc)

    async def _finished(self, cmd: Command, actor: Principal | None = None) -> None:
        """Record a command that just reached a final status."""
        lane = self._lanes.get(cmd.instance_id)
        if lane is not None:
            lane.retire(cmd)
        now = self.clock()
        if self.shared:
            if not await self.repo.claim_finish(cmd.to_doc(), now):
                await self.stored.catch_up(cmd)  # another replica recorded its end first
                return
            self.announce(cmd.instance_id, "commands")
        else:
            await self.repo.finish(cmd.to_doc(), now)
        last = cmd.history[-1] if cmd.history else {}
        await self._audit(cmd, actor, detail=last.get("detail"))

    async def _audit(self, cmd: Command, actor: Principal | None, **data: Any) -> None:
        await self.events.record(
            "command",
            vehicle_id=cmd.vehicle_id,
            instance_id=cmd.instance_id,
            actor=actor,
            data={"command_id": cmd.command_id, "type": cmd.type, "status": cmd.status, **data},
        )
