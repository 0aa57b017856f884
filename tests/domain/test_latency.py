"""The vehicle → server delay, pure: the agent's clock offset estimate (NTP-style, the
exchange with the smallest round trip kept) and the server's correction with it."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

from server.domain.latency import TELL_EVERY_S, LinkDelay, one_way_delay_s
from vehicle_client.clock import Exchange, ServerClock, best_exchange

T0 = datetime(2026, 11, 22, 10, 0, 0, tzinfo=UTC)
SKEW = timedelta(seconds=5)  # the vehicle's clock runs 5 s ahead of the server's


def ms(value: float) -> timedelta:
    return timedelta(milliseconds=value)


def exchange_at(server_at: datetime, up_ms: float, down_ms: float) -> tuple[datetime, ...]:
    """A call that reaches the server at ``server_at`` (server clock) after ``up_ms`` and is
    answered at once, back after ``down_ms``: (sent, server_time, received), the first and
    last on the vehicle's clock."""
    sent = server_at - ms(up_ms) + SKEW
    return sent, server_at, server_at + ms(down_ms) + SKEW


def test_a_clock_5_s_ahead_is_corrected_to_the_true_delay() -> None:
    clock = ServerClock()
    # Round trips of 40 to 400 ms, the slow ones lopsided (a queue on the way up).
    ways = [(200.0, 20.0), (20.0, 20.0), (350.0, 50.0), (60.0, 25.0), (22.0, 21.0)]
    for i, (up, down) in enumerate(ways):
        sent, server_time, received = exchange_at(T0 + timedelta(seconds=i), up, down)
        clock.observe(server_time, sent, received)
    # The estimate is the even 40 ms exchange's: off by at most half its round trip.
    assert clock.synced
    assert abs(clock.offset_s - (-5.0)) <= 0.0011
    assert clock.rtt_s is not None and abs(clock.rtt_s - 0.043) < 1e-6  # the latest call
    # A batch sent by the vehicle's clock and received 30 ms later by the server's.
    arrived = T0 + timedelta(seconds=10)
    sent_by_vehicle = arrived - ms(30) + SKEW
    corrected = one_way_delay_s(sent_by_vehicle, arrived, clock.offset_s)
    assert abs(corrected - 0.030) <= 0.0011
    # Without the correction the skew would be read as a delay (here, minus five seconds).
    assert one_way_delay_s(sent_by_vehicle, arrived, None) < -4.9


def test_the_smallest_round_trip_in_the_window_wins_and_old_ones_leave() -> None:
    clock = ServerClock(window=3, window_s=60.0)
    sent, server_time, received = exchange_at(T0, 5.0, 5.0)  # the best, but it will age out
    clock.observe(server_time, sent, received)
    best_offset = clock.offset_s
    for i in range(1, 3):
        sent, server_time, received = exchange_at(T0 + timedelta(seconds=i), 90.0, 10.0)
        clock.observe(server_time, sent, received)
    assert clock.offset_s == best_offset
    sent, server_time, received = exchange_at(T0 + timedelta(seconds=3), 90.0, 10.0)
    clock.observe(server_time, sent, received)  # four exchanges: the first one leaves
    assert clock.offset_s != best_offset
    assert abs(clock.offset_s - (-5.0 + 0.040)) <= 1e-6  # lopsided: off by (up - down) / 2


def test_an_exchange_whose_local_clock_stepped_back_is_left_out() -> None:
    clock = ServerClock()
    clock.observe(T0, T0 + SKEW, T0 + SKEW - ms(10))
    assert not clock.synced and clock.rtt_s is None
    assert best_exchange([Exchange(T0, T0, T0 - ms(1))]) is None


def test_link_delay_smooths_and_says_when_to_tell() -> None:
    link = LinkDelay()
    assert link.view() == (None, None)
    assert link.observe(0.020, 0.045, now=100.0) is True  # the first measure is news
    assert link.view() == (20.0, 45.0)
    assert link.observe(0.200, None, now=101.0) is False  # too soon after the last told
    assert link.delay_ms is not None and 20.0 < link.delay_ms < 200.0
    assert link.observe(0.200, None, now=100.0 + TELL_EVERY_S) is True  # moved, due again
    told = link.delay_ms
    for i in range(4):  # within the interval: taken in, not told
        assert link.observe(0.001, None, now=101.0 + TELL_EVERY_S + i * 0.1) is False
    assert link.observe(0.001, None, now=200.0) is True  # down by more than a quarter
    assert link.delay_ms is not None and link.delay_ms < told * 0.75
    steady = LinkDelay()
    steady.observe(0.020, None, now=0.0)
    assert steady.observe(0.021, None, now=TELL_EVERY_S * 3) is False  # 1 ms: not news


def test_negative_and_absurd_delays_never_break_the_view() -> None:
    link = LinkDelay()
    assert link.observe(-0.002, None, now=0.0) is True  # clocks a little apart: 0 ms
    assert link.view() == (0.0, None)
    assert link.observe(1e6, None, now=100.0) is False  # a clock gone wrong: left out
    assert link.observe(float("nan"), None, now=200.0) is False
    assert link.view() == (0.0, None)
