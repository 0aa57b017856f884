"""Presence by contact age (server.domain.presence): the one-comparison check of a pass
over many instances says what presence_of says."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

from server.domain.presence import is_online, online_since, presence_of

NOW = datetime(2026, 11, 25, 12, 0, 0, tzinfo=UTC)


def test_is_online_agrees_with_presence_of() -> None:
    since = online_since(NOW, 3.0)
    ages = [None, 0.0, 1.0, 2.999, 3.0, 3.001, 5.0, 10.0, 11.0]
    for age in ages:
        seen = None if age is None else NOW - timedelta(seconds=age)
        for finished in (False, True):
            for polling in (False, True):
                told = presence_of(
                    seen,
                    NOW,
                    stale_after_s=3.0,
                    offline_after_s=10.0,
                    finished=finished,
                    polling=polling,
                )
                online = is_online(seen, since, finished=finished, polling=polling)
                assert online == (told == "online"), (age, finished, polling, told)
