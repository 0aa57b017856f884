"""What the gateway sends one local unit: a bounded queue with one writer task.

Everything for a unit (acks, errors, events, ``routes``, media frames) goes
through its queue, so a unit that reads slowly never holds up the one that
published, nor the uplink's reader. Two rules keep the queue bounded:

- a **media** frame waits at most once per topic: a newer frame on the
  same topic takes the place of the one still waiting (latest wins, as on
  the server's sockets), counted in ``replaced``;
- past ``size`` waiting frames the oldest is dropped, counted, and a
  ``lagging {dropped}`` push goes out before the next frame.

An event on a topic the unit subscribed to with ``throttle_ms`` goes at most
once every ``throttle_ms`` (the latest one held back goes when it is over), as
the server does for each socket (``fleet_protocol.throttle``).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections import deque

from websockets.asyncio.server import ServerConnection
from websockets.exceptions import ConnectionClosed

from fleet_protocol import ErrorBody
from fleet_protocol.throttle import Throttle
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
        self._throttle: Throttle[str] = Throttle()
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

    def put_event(self, topic: str, frame: str, throttle_ms: int) -> None:
        """An event on ``topic``: at once, or held back while its ``throttle_ms`` runs."""
        if self.closed:
            return
        now = asyncio.get_running_loop().time()
        if throttle_ms <= 0 or self._throttle.offer(topic, frame, throttle_ms / 1000, now):
            self._append(frame)
        else:
            self._wake.set()  # the writer sends it when it is due

    def forget(self, topics: list[str]) -> None:
        """The unit unsubscribed: what was held back of these topics is not sent."""
        for topic in topics:
            self._throttle.forget(topic)

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
            loop = asyncio.get_running_loop()
            while True:
                while not self._order:
                    self._wake.clear()
                    for _, held in self._throttle.due(loop.time()):
                        self._append(held)
                    if self._order:
                        break
                    due = self._throttle.next_due()
                    with contextlib.suppress(TimeoutError):
                        wait = None if due is None else max(0.0, due - loop.time())
                        await asyncio.wait_for(self._wake.wait(), wait)
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
