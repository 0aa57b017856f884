"""Exponential backoff with full jitter (pure; the caller sleeps)."""

from __future__ import annotations

import random
from dataclasses import dataclass, field


@dataclass
class Backoff:
    initial_s: float = 0.5
    #: The longest wait: a boat out of contact holds its failsafe and shows offline
    #: meanwhile, so a link that came back is tried within 5-10 s (the jitter spreads
    #: a fleet's reconnections after a server restart).
    max_s: float = 10.0
    factor: float = 2.0
    rng: random.Random = field(default_factory=random.Random)
    attempt: int = 0

    def next_delay(self, at_least_s: float | None = None) -> float:
        """The wait before the next try: uniform in [0, cap], cap doubling per failure.

        ``at_least_s`` (a server's ``Retry-After``) is honoured as a floor.
        """
        cap = min(self.max_s, self.initial_s * self.factor**self.attempt)
        self.attempt += 1
        delay = self.rng.uniform(cap / 2, cap)
        return max(delay, at_least_s or 0.0)

    def reset(self) -> None:
        self.attempt = 0
