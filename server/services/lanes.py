"""One command lane per instance: its active commands, recent finished ones, waiters.

In-memory hot state of :mod:`server.services.commands`; no I/O here.
"""

from __future__ import annotations

import asyncio
from collections import deque

from server.domain.commands import ABORT_STATUSES, Command


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
