"""One command lane per instance: its active commands, recent finished ones, waiters.

In-memory hot state of :mod:`server.services.commands`. :class:`Lane` does no
I/O; :class:`StoredLanes` reads the lanes back from the store when several
replicas share it (the store is the truth, the lanes a cache).
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable, Mapping

from server.domain.commands import ABORT_STATUSES, Command
from server.errors import NotFound
from server.storage.commands import CommandsRepo


class Lane:
    """The commands of one instance, as the server holds them in memory."""

    def __init__(self, instance_id: str, recent_limit: int) -> None:
        self.instance_id = instance_id
        self.active: dict[str, Command] = {}
        self.recent: deque[Command] = deque()
        self.recent_limit = recent_limit
        self.history_loaded = False
        #: Commands handed out that ended cancelled or expired: told in the next ``abort``.
        self.aborts: list[str] = []
        self.polls = 0
        self._wake = asyncio.Event()

    def waiter(self) -> asyncio.Event:
        """The event the next :meth:`wake` sets. Take it *before* looking at the queue."""
        return self._wake

    def wake(self) -> None:
        self._wake.set()
        self._wake = asyncio.Event()

    def add(self, cmd: Command) -> None:
        self.active[cmd.command_id] = cmd

    def retire(self, cmd: Command) -> Command | None:
        """Move an ended command to ``recent``; returns the one pushed out, if any."""
        self.active.pop(cmd.command_id, None)
        if cmd.deliveries and cmd.status in ABORT_STATUSES:
            self.aborts.append(cmd.command_id)
        self.recent.append(cmd)
        if len(self.recent) > self.recent_limit:
            return self.recent.popleft()
        return None

    def remember(self, older: list[Command]) -> None:
        """Finished commands read back from the store: older than those in ``recent``."""
        self.history_loaded = True
        known = {c.command_id for c in self.recent}
        fresh = sorted((c for c in older if c.command_id not in known), key=lambda c: c.seq)
        self.recent.extendleft(reversed(fresh))
        while len(self.recent) > self.recent_limit:
            self.recent.popleft()

    def merge(self, stored: list[Command]) -> list[Command]:
        """Fold in the active commands as the store holds them (several replicas: another
        may have queued or moved some). Returns the active ones the store no longer lists:
        ended elsewhere, or still being written here."""
        listed = set()
        for fresh in stored:
            listed.add(fresh.command_id)
            mine = self.get(fresh.command_id)
            if mine is None:
                self.active[fresh.command_id] = fresh
            elif fresh.command_id in self.active:
                mine.catch_up(fresh)
        return [c for c in self.active.values() if c.command_id not in listed]

    def take_aborts(self) -> list[str]:
        out, self.aborts = self.aborts, []
        return out

    def get(self, command_id: str) -> Command | None:
        cmd = self.active.get(command_id)
        if cmd is not None:
            return cmd
        for old in self.recent:
            if old.command_id == command_id:
                return old
        return None


class StoredLanes:
    """Several replicas: catch the lanes up with the store, and read commands from it."""

    def __init__(
        self, repo: CommandsRepo, lanes: Mapping[str, Lane], lane: Callable[[str], Lane]
    ) -> None:
        self.repo = repo
        self.lanes = lanes
        self.lane = lane

    async def sync(self, instance_id: str) -> Lane:
        """The instance's lane, caught up with its active commands in the store."""
        lane = self.lane(instance_id)
        stored = [Command.from_doc(d) for d in await self.repo.active_for(instance_id)]
        for gone in lane.merge(stored):
            if await self.catch_up(gone) and gone.final:
                lane.retire(gone)  # ended on another replica
        return lane

    async def find(self, command_id: str, read_only: bool) -> Command:
        """A command as the store has it; to act on, this replica's copy caught up."""
        doc = await self.repo.get(command_id)
        if doc is None:  # not written yet (a submit on its way here), or none
            for lane in self.lanes.values():
                if (cmd := lane.get(command_id)) is not None:
                    return cmd
            raise NotFound(f"no command {command_id}")
        stored = Command.from_doc(doc)
        if read_only or stored.final:
            return stored
        lane = await self.sync(stored.instance_id)
        return lane.get(command_id) or stored

    async def recent(self, instance_id: str, limit: int) -> list[Command]:
        """The instance's active and recently ended commands, newest first."""
        docs = await self.repo.active_for(instance_id)
        docs += await self.repo.recent_finished(instance_id, limit)
        recent = [Command.from_doc(d) for d in docs]
        recent.sort(key=lambda c: (c.issued_at, c.seq), reverse=True)
        return recent[:limit]

    async def catch_up(self, cmd: Command) -> bool:
        """Take the stored copy's word on a command (another replica moved it); whether
        that changed it."""
        doc = await self.repo.get(cmd.command_id)
        return doc is not None and cmd.catch_up(Command.from_doc(doc))
