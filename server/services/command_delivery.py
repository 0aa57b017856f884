"""The vehicle's side of commands: hand out what is due, take the vehicle's acks.

Delivery has one path, :meth:`CommandDelivery.take`, for long polls and vehicle
sockets alike: :class:`~server.domain.events.CommandsReady` tells that an
instance has something to hand out (on submit, when a redelivery falls due).
Before a handout the instance's lapsed lease is ended, its lane caught up with
the store, and a command not yet acknowledged that was checked against an older
version of the zones is checked again. An ack moves a command on
(:mod:`server.domain.commands`); one for a command that ended meanwhile, here
or on another replica, is noted in its history, and the vehicle is told to abort
what the server ended. :class:`~server.services.commands.CommandService` builds
the operators' side and the server's own commands on this.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from datetime import datetime
from typing import Any

from fleet_protocol import format_ts
from server.domain import command_ends as ends
from server.domain import commands as life
from server.domain.access import Principal
from server.domain.clock import said_time
from server.domain.commands import AckOutcome, Command
from server.domain.events import FailsafeChanged, StateWritten
from server.errors import RateLimited
from server.metrics import Hops
from server.services.command_admission import ZoneSetSource, zone_refusal
from server.services.command_lanes import CommandLanes
from server.services.control import ControlService
from server.services.instances import InstanceService, InstanceState
from server.services.lanes import Lane
from server.settings import Settings

__all__ = ["CommandDelivery"]


class CommandDelivery(CommandLanes):
    """The vehicle's side of :class:`~server.services.commands.CommandService` (its
    base; built as it is), on the lanes of
    :class:`~server.services.command_lanes.CommandLanes`."""

    settings: Settings
    instances: InstanceService
    control: ControlService
    #: The zones as the store has them now (a handout checks its commands again).
    zones: ZoneSetSource
    #: Where the command hops are measured (``/metrics``); None: nowhere.
    hops: Hops | None

    async def get_control(
        self,
        principal: Principal,
        instance_id: str,
        wait_s: float,
        news: Callable[[InstanceState], Awaitable[object]] | None = None,
    ) -> tuple[list[Command], list[str]]:
        """Hand out what is due, waiting up to ``wait_s`` for something to come; and the
        commands handed out before that ended since (the vehicle aborts them). ``news``:
        something else the vehicle is to be told at once when it is true (a failsafe
        policy it has not applied); checked at the start and each time the lane is
        woken (:meth:`wake`)."""
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
        answered = False
        try:
            while True:
                woken = lane.waiter()
                out = await self.take(state)
                aborts = self.take_aborts(state.instance_id)
                remaining = deadline - loop.time()
                if (
                    out
                    or aborts
                    or remaining <= 0
                    or state.finished
                    or (news is not None and await news(state))
                ):
                    answered = True
                    return out, aborts
                try:
                    await asyncio.wait_for(woken.wait(), remaining)
                except TimeoutError:
                    pass
        finally:
            lane.polls -= 1
            state.polling -= 1
            if answered:  # not a poll given up (its vehicle gone): that is no contact
                self.instances.touch(state)

    def on_failsafe_changed(self, event: FailsafeChanged) -> None:
        """A vehicle's policy changed: its open long polls on this replica look again."""
        if (state := self.instances.current(event.vehicle_id)) is not None:
            self.wake(state.instance_id)

    async def take(self, state: InstanceState) -> list[Command]:
        """The commands to hand out now, in order (``stop`` first), marked delivered."""
        if state.finished:
            return []
        await self.control.end_if_lapsed(state.instance_id)  # its holder's orders with it
        lane = await self._sync(state.instance_id)
        await self._check_zones(state, lane)
        now = self.clock()
        held: list[Command] = []
        out, ended = life.handout(
            list(lane.active.values()),
            now,
            ack_timeout_s=self.settings.ack_timeout_s,
            position=state.position,
            position_current=life.position_is_current(
                state.position, state.vehicle_clock(now), self.settings.offline_after_s
            ),
            held=held,
        )
        state.drift_held = bool(held)  # handed out once a current position comes
        for cmd in ended:
            await self._finished(cmd)
        handed = []
        for cmd in out:
            if await self.repo.save_active(cmd.to_doc()):
                handed.append(cmd)
            else:  # it ended on another replica meanwhile
                await self._catch_up(cmd)
                lane.retire(cmd)
        if handed:
            self.messages.emit_now(StateWritten(state.instance_id, "commands"))
            for cmd in handed:
                self._moved(cmd)
                if self.hops is not None and cmd.deliveries == 1 and cmd.delivered_at:
                    self.hops.command_delivered((cmd.delivered_at - cmd.issued_at).total_seconds())
        return handed

    async def _check_zones(self, state: InstanceState, lane: Lane) -> None:
        """Commands not yet acknowledged and checked against an older version of the
        zones are checked again: one the zones now refuse is cancelled, saying why."""
        waiting = [
            c
            for c in lane.active.values()
            if c.zones_version is not None and c.status in life.UNACKNOWLEDGED
        ]
        if not waiting:
            return
        zones = await self.zones()
        for cmd in waiting:
            if cmd.zones_version == zones.version:
                continue
            violation = zone_refusal(zones, state, cmd.type, cmd.args)
            if violation is None:
                cmd.zones_version = zones.version  # written with its handout
            elif ends.cancel(cmd, self.clock(), f"zones_changed: {violation.message}"):
                await self._finished(cmd)

    async def acknowledge(
        self,
        principal: Principal,
        instance_id: str,
        control_mode: str | None,
        acks: list[Any],
        since: datetime | None = None,
    ) -> list[str]:
        """Apply the vehicle's acks; returns the ``abort`` list. ``since``: when the
        vehicle says it entered ``control_mode`` (its events say so)."""
        state = await self.instances.for_vehicle_caller(principal, instance_id)
        self.instances.touch(state)
        was = state.control_mode
        if since is not None and control_mode not in (None, was):  # dated on a change only
            since = said_time(since, self.clock(), state.started_at)
        moved = await self.instances.set_control_mode(state, control_mode, since)
        if moved:
            data: dict[str, Any] = {"control_mode": control_mode, "was": was}
            if since is not None:
                data["since"] = format_ts(since)
            await self.events.record(  # failsafe and local control matter to the operators
                "control_mode",
                vehicle_id=state.vehicle_id,
                instance_id=state.instance_id,
                actor=principal,
                data=data,
            )
            if "failsafe" in (was, control_mode):
                await self.events.record(
                    "failsafe_entered" if control_mode == "failsafe" else "failsafe_left",
                    vehicle_id=state.vehicle_id,
                    instance_id=state.instance_id,
                    actor=principal,
                    data=data,
                )
        lane = await self._sync(state.instance_id) if acks else self._lane(state.instance_id)
        now = self.clock()
        abort: list[str] = []
        for ack in acks:
            cmd = lane.active.get(ack.command_id) or await self._read(ack.command_id, state)
            if cmd is None:
                abort.append(ack.command_id)  # unknown here: never to be carried out
                continue
            was = cmd.status
            status, detail = life.check_plan(cmd, ack.status, ack.path_hash, ack.detail)
            if status != ack.status:
                abort.append(cmd.command_id)  # never to be carried out
            status, detail = life.superseded(status, detail)
            noted = len(cmd.history)
            outcome = life.apply_ack(cmd, status, now, progress=ack.progress, detail=detail)
            if was == "delivered" and cmd.status != was and self.hops is not None:
                self._acked_first(cmd, now)
            if outcome is AckOutcome.LATE:
                if len(cmd.history) != noted:  # a repeat, or one past the bound: not kept
                    await self.repo.note_history(cmd.command_id, cmd.history)
                if ends.ended_by_server(cmd):
                    abort.append(cmd.command_id)
            elif cmd.final:
                await self._finished(cmd)
            elif cmd.command_id in lane.active and not await self.repo.save_active(cmd.to_doc()):
                await self._catch_up(cmd)  # it ended meanwhile (here or on another replica)
                lane.retire(cmd)
                if cmd.final:  # so the ack came late: noted there, as any late ack
                    life.apply_ack(cmd, status, now, progress=ack.progress, detail=detail)
                    await self.repo.note_history(cmd.command_id, cmd.history)
                    if ends.ended_by_server(cmd):
                        abort.append(cmd.command_id)
            elif cmd.status != was:
                self._moved(cmd)
        if acks:
            self.messages.emit_now(StateWritten(state.instance_id, "commands"))
        if acks or moved:  # the vehicle forgets what it sent once it is answered (an
            await self.repo.make_durable()  # operator's submit: api/durable.py)
        abort.extend(lane.take_aborts())
        return list(dict.fromkeys(abort))

    def _acked_first(self, cmd: Command, now: datetime) -> None:
        """The vehicle's first ack of a handed-out command: its hops into ``/metrics``."""
        assert self.hops is not None
        delivered = cmd.delivered_at
        self.hops.command_acked(
            (now - delivered).total_seconds() if delivered is not None else None,
            (now - cmd.issued_at).total_seconds(),
        )
