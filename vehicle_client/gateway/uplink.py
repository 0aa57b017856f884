"""Media frames on their way up to the cloud, kept from crowding out everything else.

The vehicles' JSON ops (telemetry, acks, heartbeats, topic ops) leave
through the link as they come. Media frames wait here instead, and leave
by these rules:

- **latest wins**: at most one frame waits per topic; a newer one takes its
  place (counted in ``replaced``), so a camera faster than the link costs
  frames, not memory nor delay;
- **one at a time**: the next frame leaves once the socket has taken the
  previous one (its write buffer drained), so a JSON op waits behind at most
  one media frame;
- **paced**: at most ``per_s`` frames per second, all topics together. The
  server counts a binary frame against the connection's ops per second
  (``FLEET_WS_OPS_PER_S``); the default stays well under it, leaving the
  budget to the vehicles;
- topics take turns: the one that has waited longest goes first.

A frame that cannot leave because the link is down is dropped and counted:
media is never worth a reconnection, and the next frame will do.
"""

from __future__ import annotations

import asyncio

from vehicle_client.errors import AgentError
from vehicle_client.transport.ws import WsLink

__all__ = ["DEFAULT_MEDIA_UP_PER_S", "DEFAULT_PUBLISH_UP_PER_S", "MediaUplink", "PublishBudget"]

#: Media frames per second a gateway sends up (all topics together).
DEFAULT_MEDIA_UP_PER_S = 100.0
#: JSON publishes per second a gateway's units send up, all together: with the media
#: frames, well under the server's ops per second on one socket (``FLEET_WS_OPS_PER_S``,
#: 500), so that the vehicles' own ops (telemetry, acks) are never the ones refused.
DEFAULT_PUBLISH_UP_PER_S = 200.0


class PublishBudget:
    """A token bucket of the units' JSON publishes sent up: ``per_s`` a second, a burst
    of a second's worth. A publish over it is refused to its unit (``rate_limited``),
    never sent to be refused above while the unit is told ok."""

    def __init__(self, per_s: float = DEFAULT_PUBLISH_UP_PER_S) -> None:
        if per_s <= 0:
            raise ValueError("per_s must be above 0")
        self.per_s = per_s
        self._tokens = per_s
        self._at: float | None = None
        self.refused = 0

    def take(self, now: float) -> bool:
        """Whether one more may go up at ``now`` (a monotonic time in seconds)."""
        if self._at is not None:
            self._tokens = min(self.per_s, self._tokens + (now - self._at) * self.per_s)
        self._at = now
        if self._tokens >= 1:
            self._tokens -= 1
            return True
        self.refused += 1
        return False


class MediaUplink:
    def __init__(self, link: WsLink, per_s: float = DEFAULT_MEDIA_UP_PER_S) -> None:
        if per_s <= 0:
            raise ValueError("per_s must be above 0")
        self.link = link
        self.interval_s = 1.0 / per_s
        self._waiting: dict[str, bytes] = {}  # insertion order: who goes next
        self._wake = asyncio.Event()
        self._task: asyncio.Task[None] | None = None
        self.sent = 0
        self.replaced = 0
        self.dropped = 0

    def put(self, topic: str, frame: bytes) -> None:
        """Queue ``frame`` for ``topic`` (replacing the one still waiting, if any)."""
        if topic in self._waiting:
            self.replaced += 1
        self._waiting[topic] = frame
        self._wake.set()
        if self._task is None or self._task.done():
            self._task = asyncio.create_task(self._run(), name="media-uplink")

    @property
    def waiting(self) -> int:
        return len(self._waiting)

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        next_at = 0.0
        while True:
            while not self._waiting:
                self._wake.clear()
                await self._wake.wait()
            delay = next_at - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)  # pacing; frames coming meanwhile replace
            topic = next(iter(self._waiting))
            frame = self._waiting.pop(topic)
            next_at = loop.time() + self.interval_s
            try:
                await self.link.send_media(frame)
            except AgentError:
                self.dropped += 1
            else:
                self.sent += 1

    async def aclose(self) -> None:
        """Stop sending; what waits is dropped."""
        self._waiting.clear()
        if self._task is not None:
            self._task.cancel()
            await asyncio.wait([self._task])
