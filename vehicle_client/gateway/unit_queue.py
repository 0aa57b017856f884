"""What the gateway sends one local unit: a bounded queue with one writer task.

Everything for a unit (acks, errors, events, ``routes``, media frames) goes
through its queue, so a unit that reads slowly never holds up the one that
published, nor the uplink's reader. Two rules keep the queue bounded:

- a **media** frame waits at most once per topic: a newer frame on the
  same topic takes the place of the one still waiting (latest wins, as on
  the server's sockets), counted in ``replaced``;
- past ``size`` waiting frames the oldest is dropped, counted, and a
  ``lagging {dropped}`` push goes out before the next frame.
"""

from __future__ import annotations

import asyncio
from collections import deque

from websockets.asyncio.server import ServerConnection
from websockets.exceptions import ConnectionClosed

from fleet_protocol import ErrorBody
from fleet_protocol.ws import AckPush, ErrorPush, LaggingPush

__all__ = ["DEFAULT_UNIT_QUEUE", "UnitQueue"]

#: Frames that may wait for one local unit before the oldest is dropped.
DEFAULT_UNIT_QUEUE = 256


class UnitQueue:
    """The frames on their way to one local unit's connection."""

    def __init__(self, conn: ServerConnection, size: int = DEFAULT_UNIT_QUEUE) -> None:
        self.conn = conn
        self.size = size
        #: Text frames as they are; a media topic stands for its latest frame in ``_media``.
        self._order: deque[str | _MediaSlot] = deque()
        self._media: dict[str, bytes] = {}
        self._wake = asyncio.Event()
        self._lagging = 0
        self.dropped = 0
        self.replaced = 0
        self.sent = 0
        self.closed = False
        self._writer = asyncio.create_task(self._write(), name="unit-queue")

    def put(self, frame: str) -> None:
        if not self.closed:
            self._append(frame)

    def refuse(self, op_id: str | None, error: ErrorBody) -> None:
        """An op refused: its ack when it has an ``id``, else an ``error`` push."""
        push = AckPush.failure(op_id, error) if op_id else ErrorPush(error=error)
        self.put(push.frame())

    def put_media(self, topic: str, frame: bytes) -> None:
        """A media frame: it replaces the one of the same topic still waiting, if any."""
        if self.closed:
            return
        if topic in self._media:
            self._media[topic] = frame
            self.replaced += 1
            return
        self._media[topic] = frame
        self._append(_MediaSlot(topic))

    def _append(self, item: str | _MediaSlot) -> None:
        self._order.append(item)
        while len(self._order) > self.size:
            oldest = self._order.popleft()
            if isinstance(oldest, _MediaSlot):
                del self._media[oldest.topic]
            self.dropped += 1
            self._lagging += 1
        self._wake.set()

    async def _write(self) -> None:
        try:
            while True:
                while not self._order:
                    self._wake.clear()
                    await self._wake.wait()
                if self._lagging:
                    lagging = LaggingPush(dropped=self._lagging, total=self.dropped)
                    self._lagging = 0
                    await self.conn.send(lagging.frame())
                item = self._order.popleft()
                frame = self._media.pop(item.topic) if isinstance(item, _MediaSlot) else item
                await self.conn.send(frame)
                self.sent += 1
        except ConnectionClosed:
            self.closed = True
            self._order.clear()
            self._media.clear()

    async def close(self) -> None:
        """Stop the writer; what still waits is not sent."""
        self.closed = True
        self._writer.cancel()
        await asyncio.wait([self._writer])  # a cancel of the caller still goes through


class _MediaSlot:
    """The place in the queue of a topic's latest media frame."""

    __slots__ = ("topic",)

    def __init__(self, topic: str) -> None:
        self.topic = topic
