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


def test_a_timestamp_field_reads_every_offset_into_utc_within_its_range():
    from pydantic import TypeAdapter

    from fleet_protocol.common import Timestamp

    read = TypeAdapter(Timestamp).validate_json
    expected = datetime(2026, 5, 1, 12, 0, 3, 456000, tzinfo=UTC)
    for text in (
        "2026-05-01T12:00:03.456Z",
        "2026-05-01T12:00:03.456+00:00",
        "2026-05-01T14:00:03.456+02:00",
        "2026-05-01T12:00:03.456",  # naive: UTC
    ):
        value = read(f'"{text}"')
        assert value == expected, text
        assert value.utcoffset() == timedelta(0), text
        assert format_ts(value) == "2026-05-01T12:00:03.456Z", text
    assert read('"1970-01-01T00:00:00Z"') == datetime(1970, 1, 1, tzinfo=UTC)
    last = datetime(2099, 12, 31, 23, 59, 59, 999999, tzinfo=UTC)
    assert read('"2099-12-31T23:59:59.999999Z"') == last
    assert read('"2100-01-01T00:59:59.999999+01:00"') == last


def test_a_point_in_time_stops_short_of_2100_and_a_window_bound_reaches_it():
    """Every point in time is in the widest window: 1970 included to 2100 excluded, as a
    window's ``to`` is (a sample at 2100 itself was stored, and no window held it)."""
    from pydantic import TypeAdapter, ValidationError

    from fleet_protocol.common import TimeBound, Timestamp

    point, bound = TypeAdapter(Timestamp).validate_json, TypeAdapter(TimeBound).validate_json
    for text in ('"2100-01-01T00:00:00Z"', '"2100-01-01T01:00:00+01:00"'):
        assert bound(text) == datetime(2100, 1, 1, tzinfo=UTC)
        try:
            point(text)
        except ValidationError as exc:
            (error,) = exc.errors()
            assert "to before 2100-01-01T00:00:00.000Z" in error["msg"], text
        else:
            raise AssertionError(f"{text} was read as a point in time")
    assert bound('"1970-01-01T00:00:00Z"') == datetime(1970, 1, 1, tzinfo=UTC)
    for text in ('"2100-01-01T00:00:00.001Z"', '"1969-12-31T23:59:59.999Z"'):
        try:
            bound(text)
        except ValidationError as exc:
            assert exc.errors()[0]["type"] == "timestamp", text
        else:
            raise AssertionError(f"{text} was read as a bound")


def test_a_timestamp_out_of_range_or_not_a_time_is_one_error_naming_the_range():
    from pydantic import TypeAdapter, ValidationError

    from fleet_protocol.common import Timestamp

    read = TypeAdapter(Timestamp).validate_json
    for text in (
        '"1969-12-31T23:59:59Z"',
        '"2100-01-01T00:00:01Z"',
        '"2099-12-31T23:59:30-00:01"',  # 2100-01-01T00:00:30Z
        '"2100-01-01T00:00:01"',  # naive: UTC
        '"0001-01-01T00:00:00+01:00"',
        '"yesterday"',
    ):
        try:
            read(text)
        except ValidationError as exc:
            (error,) = exc.errors()
            assert error["type"] == "timestamp", text
            assert "1970-01-01T00:00:00.000Z" in error["msg"], text
            assert "2100-01-01T00:00:00.000Z" in error["msg"], text
        else:
            raise AssertionError(f"{text} was read")
