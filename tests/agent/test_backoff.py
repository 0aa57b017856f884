"""The agent's reconnect back-off (pure): doubling with jitter, at most 10 s, a server's
Retry-After as a floor."""

from __future__ import annotations

import random

from vehicle_client.backoff import Backoff


def test_the_wait_doubles_to_at_most_ten_seconds() -> None:
    backoff = Backoff(rng=random.Random(7))
    waits = [backoff.next_delay() for _ in range(12)]
    assert 0.25 <= waits[0] <= 0.5 and 0.5 <= waits[1] <= 1.0
    assert all(5.0 <= w <= 10.0 for w in waits[6:])  # a link back is tried within 10 s
    backoff.reset()
    assert backoff.next_delay() <= 0.5


def test_a_retry_after_is_a_floor() -> None:
    assert Backoff(rng=random.Random(1)).next_delay(at_least_s=42.0) == 42.0
