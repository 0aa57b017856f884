"""The server's clock as seen from the vehicle (pure).

Command expiry is judged by the vehicle's own clock corrected with the
``server_time`` the server sends (``start_instance``, ``heartbeat``): the
offset is the server time minus the local time at the middle of the call.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta


@dataclass
class ServerClock:
    offset_s: float = 0.0
    synced: bool = False

    def observe(self, server_time: datetime, sent_at: datetime, received_at: datetime) -> None:
        """Take the offset from a call sent and answered at the given local times."""
        middle = sent_at + (received_at - sent_at) / 2
        self.offset_s = (server_time - middle).total_seconds()
        self.synced = True

    def server_now(self, local_now: datetime) -> datetime:
        return local_now + timedelta(seconds=self.offset_s)
