"""One timer for the keepalive pings of every WebSocket a server holds.

uvicorn pings each socket on a timer of its own: every ``ws_ping_interval`` it
arms a timer to send a ping and another to wait for the pong. With 10,000
sockets that is 500 timers armed a second, each living 20 s, and the
collector scans them all again and again (measured at 10,000 vehicles: about
3 % of a core and half of each middle-generation pass).

:class:`KeepaliveWheel` holds a server's sockets in ``SLOTS`` slots and visits
one slot every ``interval / SLOTS`` seconds, so each socket once an interval.
A socket keeps two facts for it: whether its ping waits for a pong
(:meth:`Keepalive.ping_due`), and whether its peer sent anything since the
last visit (:meth:`Keepalive.heard_since`; a pong alone does not count, so an
idle socket is pinged every interval). At a visit:

- a ping left unanswered since the last visit, a whole interval: the peer is
  gone and the socket is closed (1011), as uvicorn does after its timeout;
- a socket that heard from its peer since the last visit is alive: no ping
  (a vehicle sending telemetry every second is never pinged);
- any other is pinged.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Protocol

__all__ = ["SLOTS", "Keepalive", "KeepaliveWheel"]

log = logging.getLogger("fleet.ws")

#: Slots of the wheel: one visited every ``interval / SLOTS`` seconds.
SLOTS = 20


class Keepalive(Protocol):
    """What the wheel needs of a socket."""

    def ping_due(self) -> bool:
        """Whether a ping is waiting for its pong."""

    def heard_since(self) -> bool:
        """Whether the peer sent anything since the last visit (and forget it)."""

    def send_ping(self) -> None: ...

    def ping_lost(self) -> None:
        """Close the socket: its peer did not answer a ping for a whole interval."""


class KeepaliveWheel:
    """The sockets of one server on one event loop, each visited once an ``interval``."""

    def __init__(self, loop: asyncio.AbstractEventLoop, interval: float) -> None:
        self.loop = loop
        self.interval = interval
        self._slots: list[dict[Keepalive, None]] = [{} for _ in range(SLOTS)]
        self._where: dict[Keepalive, int] = {}
        self._hand = 0  # the slot visited next
        self._timer: asyncio.TimerHandle | None = None

    def __len__(self) -> int:
        return len(self._where)

    def add(self, socket: Keepalive) -> None:
        """Watch ``socket``: its first visit is an interval away (into the slot the hand
        has just left)."""
        slot = (self._hand - 1) % SLOTS
        self._slots[slot][socket] = None
        self._where[socket] = slot
        if self._timer is None:
            self._timer = self.loop.call_later(self.interval / SLOTS, self._tick)

    def discard(self, socket: Keepalive) -> None:
        slot = self._where.pop(socket, None)
        if slot is not None:
            self._slots[slot].pop(socket, None)
        if not self._where and self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _tick(self) -> None:
        slot = self._slots[self._hand]
        self._hand = (self._hand + 1) % SLOTS
        self._timer = self.loop.call_later(self.interval / SLOTS, self._tick)
        for socket in list(slot):
            try:
                self._visit(socket)
            except Exception:  # one socket's failure is not every other socket's
                log.exception("keepalive of a WebSocket failed; it is no longer pinged")
                self.discard(socket)

    @staticmethod
    def _visit(socket: Keepalive) -> None:
        if socket.ping_due():
            socket.ping_lost()
        elif not socket.heard_since():
            socket.send_ping()
