"""One command lane per instance: this replica's copy of its active commands, and who waits.

The store is the truth (``commands_active``); a lane is caught up with it
before its commands are handed out, acknowledged, cancelled or expired
(:meth:`Lane.merge`). A lane does no I/O.
"""

from __future__ import annotations

import asyncio

from server.domain.command_ends import ended_by_server
from server.domain.commands import Command


class Lane:
    def __init__(self, instance_id: str) -> None:
        self.instance_id = instance_id
        self.active: dict[str, Command] = {}
        #: Commands handed out that ended cancelled or expired: told in the next ``abort``.
        self.aborts: list[str] = []
        #: Commands this replica ended whose end the store may not hold yet: a read of
        #: the store in between still lists them as active, and must not bring them back.
        self._ending: set[str] = set()
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

    def retire(self, cmd: Command) -> None:
        """An active command ended: the vehicle is told to abort it if it had it."""
        self._ending.add(cmd.command_id)
        if self.active.pop(cmd.command_id, None) is None:
            return
        if cmd.deliveries and ended_by_server(cmd):
            self.aborts.append(cmd.command_id)

    def merge(self, stored: list[Command]) -> list[Command]:
        """Fold in the active commands as the store holds them (another replica may have
        queued or moved some). Returns the copies the store no longer lists: they ended."""
        listed = set()
        for fresh in stored:
            listed.add(fresh.command_id)
            if fresh.command_id in self._ending:
                continue  # ended here; its end is on its way to the store
            mine = self.active.get(fresh.command_id)
            if mine is None:
                self.active[fresh.command_id] = fresh
            else:
                mine.catch_up(fresh)
        self._ending &= listed  # the store holds those ends now
        return [c for c in self.active.values() if c.command_id not in listed]

    def take_aborts(self) -> list[str]:
        out, self.aborts = self.aborts, []
        return out
