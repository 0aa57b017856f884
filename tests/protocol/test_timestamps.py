"""The contract's one time format, and the cheap 'now' the live path stamps events with."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta, timezone

from fleet_protocol.common import format_ts, now_ts, parse_ts, utcnow


def test_format_ts_is_utc_with_milliseconds_and_z():
    value = datetime(2026, 5, 1, 12, 0, 3, 456789, tzinfo=UTC)
    assert format_ts(value) == "2026-05-01T12:00:03.456Z"
    assert format_ts(value.replace(microsecond=0)) == "2026-05-01T12:00:03.000Z"


def test_format_ts_converts_other_offsets_and_naive_values_to_utc():
    plus_two = datetime(2026, 5, 1, 14, 0, 0, 1000, tzinfo=timezone(timedelta(hours=2)))
    assert format_ts(plus_two) == "2026-05-01T12:00:00.001Z"
    assert format_ts(datetime(2026, 5, 1, 12, 0)) == "2026-05-01T12:00:00.000Z"
    assert parse_ts(format_ts(plus_two)) == datetime(2026, 5, 1, 12, 0, 0, 1000, tzinfo=UTC)


def test_now_ts_lies_between_two_readings_of_the_clock():
    for _ in range(2000):  # crosses second boundaries now and then: the cached prefix moves
        before = format_ts(utcnow())
        stamp = now_ts()
        after = format_ts(utcnow())
        assert before <= stamp <= after, (before, stamp, after)
        assert len(stamp) == 24 and stamp.endswith("Z")
