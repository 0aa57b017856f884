"""This replica's copies of the commands: a :class:`~server.services.lanes.Lane` per
instance, kept in step with the store.

The store is the record (``commands_active``, and ``commands`` for those that
ended); a lane is caught up with it before a command is handed out, acked,
cancelled or expired (:meth:`CommandLanes._sync`), and a command's end is
recorded once for all replicas (:meth:`CommandLanes._finished`: the first
replica to insert it into the history).
:class:`~server.services.command_delivery.CommandDelivery` (the vehicle's side)
and :class:`~server.services.commands.CommandService` build the command life on
these.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import KeysView
from typing import Any

from server.domain import command_ends as ends
from server.domain import commands as life
from server.domain.access import Principal
from server.domain.clock import Clock
from server.domain.commands import Command
from server.domain.events import CommandMoved, CommandsReady, StateWritten
from server.errors import NotFound
from server.services.events import EventService
from server.services.instances import InstanceState
from server.services.lanes import Lane
from server.services.messagebus import MessageBus
from server.storage.commands import CommandsRepo

__all__ = ["CommandLanes"]


class CommandLanes:
    def __init__(
        self, repo: CommandsRepo, events: EventService, messages: MessageBus, clock: Clock
    ) -> None:
        self.repo = repo
        self.events = events
        self.messages = messages
        self.clock = clock
        self._lanes: dict[str, Lane] = {}

    def counts_by_status(self) -> dict[str, int]:
        """Active commands by status (for /metrics)."""
        return dict(
            Counter(c.status for lane in self._lanes.values() for c in lane.active.values())
        )

    async def refresh(self, instance_id: str) -> None:
        """Another replica moved the instance's commands: catch up, if this one keeps
        them. Commands new here are handed out (to this replica's socket, or through
        the nudge), the long polls woken."""
        if (lane := self._lanes.get(instance_id)) is None:
            return
        known = set(lane.active)
        await self._sync(instance_id)
        if set(lane.active) - known or lane.aborts:
            self._ready(lane)
        else:
            lane.wake()

    def ready(self, instance_id: str) -> None:
        """The instance may have something to hand out now (a command held for a current
        position, which came): its long polls and its socket look again."""
        if (lane := self._lanes.get(instance_id)) is not None:
            self._ready(lane)

    def wake(self, instance_id: str) -> None:
        """The instance's open long polls on this replica look again (something else
        than its commands may be news for the vehicle)."""
        if (lane := self._lanes.get(instance_id)) is not None:
            lane.wake()

    def take_aborts(self, instance_id: str) -> list[str]:
        """The commands handed to the instance's vehicle that ended since it was last told
        (each told once: by the long poll, the socket or ``update_fbmessage``)."""
        lane = self._lanes.get(instance_id)
        return lane.take_aborts() if lane is not None else []

    @property
    def lane_ids(self) -> KeysView[str]:
        return self._lanes.keys()

    def forget(self, instance_id: str) -> None:
        """The instance finished on another replica (which ended its commands)."""
        if (lane := self._lanes.pop(instance_id, None)) is not None:
            lane.wake()

    async def reconcile(self, state: InstanceState, active: list[str]) -> list[str]:
        """A vehicle (re)started its instance naming the commands it still carries out or
        has an ack to send for (``active_commands``). Each other one it had acknowledged
        is ``failed`` (:data:`~server.domain.commands.DROPPED`); returns those it names
        that the server has ended or does not know: the vehicle aborts them."""
        lane = await self._sync(state.instance_id)
        named = set(active)
        dropped = ends.dropped(list(lane.active.values()), named)
        now = self.clock()
        for cmd in dropped:
            life.apply_ack(cmd, "failed", now, detail=ends.DROPPED)
            await self._finished(cmd)
        abort = []
        for command_id in dict.fromkeys(active):
            if command_id not in lane.active:  # the lane holds every active one after _sync
                abort.append(command_id)
        if dropped:
            await self.repo.make_durable()
        return abort

    # ---- internals ------------------------------------------------------------------
    def _lane(self, instance_id: str) -> Lane:
        if (lane := self._lanes.get(instance_id)) is None:
            lane = self._lanes[instance_id] = Lane(instance_id)
        return lane

    async def _sync(self, instance_id: str) -> Lane:
        """The instance's lane, caught up with its active commands in the store."""
        docs = await self.repo.active_for(instance_id)
        return await self._merge(instance_id, [Command.from_doc(d) for d in docs])

    async def _sync_many(self, instance_ids: list[str]) -> None:
        """:meth:`_sync` for several instances, in one read."""
        if len(instance_ids) <= 1:
            for instance_id in instance_ids:
                await self._sync(instance_id)
            return
        by_instance: dict[str, list[Command]] = {i: [] for i in instance_ids}
        for doc in await self.repo.active_for_many(instance_ids):
            by_instance[doc["instance_id"]].append(Command.from_doc(doc))
        for instance_id, stored in by_instance.items():
            await self._merge(instance_id, stored)

    async def _merge(self, instance_id: str, stored: list[Command]) -> Lane:
        lane = self._lane(instance_id)
        for gone in lane.merge(stored):
            if await self._catch_up(gone) and gone.final:
                lane.retire(gone)  # ended on another replica
        return lane

    def _ready(self, lane: Lane) -> None:
        lane.wake()
        self.messages.emit_now(CommandsReady(lane.instance_id))

    async def _find(self, command_id: str) -> Command:
        """A command to act on: this replica's copy, caught up with the store."""
        doc = await self.repo.get(command_id)
        if doc is None:
            for lane in self._lanes.values():  # not written yet: a submit on its way here
                if (cmd := lane.active.get(command_id)) is not None:
                    return cmd
            raise NotFound(f"no command {command_id}")
        stored = Command.from_doc(doc)
        if stored.final:
            return stored
        lane = await self._sync(stored.instance_id)
        return lane.active.get(command_id) or stored

    async def _read(self, command_id: str, state: InstanceState | None = None) -> Command | None:
        """A command as the store has it (of ``state``'s instance, when given)."""
        doc = await self.repo.get(command_id)
        if doc is None or (state is not None and doc["instance_id"] != state.instance_id):
            return None
        return Command.from_doc(doc)

    async def _catch_up(self, cmd: Command) -> bool:
        """Take the stored copy's word on a command (another replica moved it); whether
        that changed it."""
        stored = await self._read(cmd.command_id)
        return stored is not None and cmd.catch_up(stored)

    async def _finished(self, cmd: Command, actor: Principal | None = None) -> None:
        """Record a command that just reached a final status (once, on every replica).
        One the vehicle had been handed and must now drop (cancelled, expired) is told to
        it at once: the long poll returns, the socket gets an ``abort`` push."""
        lane = self._lanes.get(cmd.instance_id)
        if lane is not None:
            lane.retire(cmd)
        recorded = await self.repo.finish(cmd.to_doc(), self.clock())
        if lane is not None and lane.aborts:  # once the store no longer lists it as active
            self._ready(lane)
        if not recorded:
            await self._catch_up(cmd)  # another replica recorded its end first
            return
        self.messages.emit_now(StateWritten(cmd.instance_id, "commands"))
        last = cmd.history[-1] if cmd.history else {}
        await self._audit(cmd, actor, detail=last.get("detail"))

    def _moved(self, cmd: Command) -> None:
        last = cmd.history[-1] if cmd.history else {}
        self.messages.emit_now(
            CommandMoved(
                cmd.vehicle_id,
                cmd.command_id,
                cmd.type,
                cmd.status,
                last.get("detail"),
                cmd.progress,
                cmd.issued_by,
            )
        )

    async def _audit(self, cmd: Command, actor: Principal | None, **data: Any) -> None:
        await self.events.record(
            "command",
            vehicle_id=cmd.vehicle_id,
            instance_id=cmd.instance_id,
            actor=actor,
            data={
                "command_id": cmd.command_id,
                "type": cmd.type,
                "status": cmd.status,
                "issued_by": cmd.issued_by,
                **data,
            },
        )
