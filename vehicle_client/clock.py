"""The server's clock as seen from the vehicle (pure).

Command expiry is judged by the vehicle's own clock corrected with the
``server_time`` the server sends (``start_instance``, ``heartbeat``,
``update_param``), and the server corrects the vehicle → server delay with
the offset the vehicle reports (docs/live.md, "Latency per hop").

The estimate is NTP's: a call sent at local ``t1``, answered with the
server's ``T`` and received at local ``t2`` gives the offset ``T - (t1 +
t2) / 2`` (server minus local), off by at most half the round trip ``t2 -
t1``, and by less the more even the two ways are. Of the recent exchanges,
the one with the smallest round trip is kept: it was least held up on the
way, so its offset is the surest.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from datetime import datetime, timedelta

#: Exchanges the estimate is taken from: at most this many, none older than this.
WINDOW = 16
WINDOW_S = 120.0


@dataclass(frozen=True, slots=True)
class Exchange:
    """One call: sent and received by the local clock, ``server_time`` by the server's."""

    sent: datetime
    server_time: datetime
    received: datetime

    @property
    def rtt_s(self) -> float:
        return (self.received - self.sent).total_seconds()

    @property
    def offset_s(self) -> float:
        """The server's clock minus the local one, at the middle of the call."""
        return (self.server_time - (self.sent + (self.received - self.sent) / 2)).total_seconds()


def best_exchange(exchanges: Iterable[Exchange]) -> Exchange | None:
    """The exchange with the smallest round trip (the surest offset); None if none."""
    return min((e for e in exchanges if e.rtt_s >= 0), key=lambda e: e.rtt_s, default=None)


@dataclass
class ServerClock:
    offset_s: float = 0.0
    synced: bool = False
    #: The round trip of the latest call (seconds), None before the first.
    rtt_s: float | None = None
    window: int = WINDOW
    window_s: float = WINDOW_S
    _recent: deque[Exchange] = field(default_factory=deque, repr=False)

    def observe(self, server_time: datetime, sent_at: datetime, received_at: datetime) -> None:
        """Take a call sent and answered at the given local times into the estimate."""
        exchange = Exchange(sent_at, server_time, received_at)
        if exchange.rtt_s < 0:
            return  # the local clock stepped back during the call: nothing to learn
        self.rtt_s = exchange.rtt_s
        recent = self._recent
        recent.append(exchange)
        oldest = received_at - timedelta(seconds=self.window_s)
        while len(recent) > self.window or recent[0].received < oldest:
            recent.popleft()
        best = best_exchange(recent)
        if best is not None:
            self.offset_s = best.offset_s
            self.synced = True

    def server_now(self, local_now: datetime) -> datetime:
        return local_now + timedelta(seconds=self.offset_s)
