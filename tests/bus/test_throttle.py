"""The throttle alone, with time passed in."""

from __future__ import annotations

import pytest

from fleet_protocol.throttle import Throttle


def test_first_goes_at_once_then_the_latest_is_held_until_the_interval_is_over():
    throttle: Throttle[str] = Throttle()
    assert throttle.offer("t", "v1", 0.1, now=0.0)
    assert not throttle.offer("t", "v2", 0.1, now=0.02)
    assert not throttle.offer("t", "v3", 0.1, now=0.05)
    assert throttle.next_due() == 0.1
    assert throttle.due(now=0.09) == []
    assert throttle.due(now=0.1) == [("t", "v3")]
    assert throttle.held() == 0
    # The release counts as a send: the next one waits a full interval again.
    assert not throttle.offer("t", "v4", 0.1, now=0.15)
    assert throttle.due(now=0.2) == [("t", "v4")]


def test_after_a_quiet_interval_an_item_goes_at_once():
    throttle: Throttle[str] = Throttle()
    assert throttle.offer("t", "v1", 0.1, now=0.0)
    assert throttle.offer("t", "v2", 0.1, now=0.5)
    assert throttle.next_due() is None


def test_keys_are_independent():
    throttle: Throttle[str] = Throttle()
    assert throttle.offer("a", "a1", 1.0, now=0.0)
    assert throttle.offer("b", "b1", 0.2, now=0.1)
    assert not throttle.offer("a", "a2", 1.0, now=0.2)
    assert not throttle.offer("b", "b2", 0.2, now=0.2)
    assert throttle.next_due() == pytest.approx(0.3)
    assert throttle.due(now=0.5) == [("b", "b2")]
    assert throttle.due(now=1.0) == [("a", "a2")]


def test_forget_drops_the_held_item_and_the_history():
    throttle: Throttle[str] = Throttle()
    throttle.offer("t", "v1", 1.0, now=0.0)
    throttle.offer("t", "v2", 1.0, now=0.1)
    throttle.forget("t")
    assert throttle.due(now=5.0) == []
    assert throttle.offer("t", "v3", 1.0, now=0.2)
