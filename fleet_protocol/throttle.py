"""Per-topic throttling, like rosbridge's ``throttle_rate``: the rule of a subscription's
``throttle_ms``, kept by the server for each socket and by a gateway for each of its
local units. Pure: time is passed in.

At most one item per key every ``interval_s``: the first goes at once, the
ones that come sooner are held back, each replacing the one held before
(the latest value wins), and the held one goes when the interval is over.
"""

from __future__ import annotations

from typing import Generic, TypeVar

__all__ = ["Throttle"]

T = TypeVar("T")


class Throttle(Generic[T]):
    def __init__(self) -> None:
        self._last_sent: dict[str, float] = {}
        self._held: dict[str, tuple[T, float]] = {}

    def offer(self, key: str, item: T, interval_s: float, now: float) -> bool:
        """Whether ``item`` goes now (recorded as sent); if not, it is held back."""
        last = self._last_sent.get(key)
        if key not in self._held and (last is None or now - last >= interval_s):
            self._last_sent[key] = now
            return True
        self._held[key] = (item, interval_s)
        return False

    def due(self, now: float) -> list[tuple[str, T]]:
        """The held items whose interval is over, oldest key first; recorded as sent."""
        ready = [
            key
            for key, (_, interval_s) in self._held.items()
            if now - self._last_sent.get(key, now) >= interval_s
        ]
        released = []
        for key in ready:
            item, _ = self._held.pop(key)
            self._last_sent[key] = now
            released.append((key, item))
        return released

    def next_due(self) -> float | None:
        """When the earliest held item is due; ``None`` if nothing is held."""
        times = [self._last_sent[key] + interval for key, (_, interval) in self._held.items()]
        return min(times, default=None)

    def held(self) -> int:
        return len(self._held)

    def __bool__(self) -> bool:
        """Whether anything is held back (nothing can be due otherwise)."""
        return bool(self._held)

    def forget(self, key: str) -> None:
        """Drop what is known of ``key`` (on unsubscribe)."""
        self._last_sent.pop(key, None)
        self._held.pop(key, None)
