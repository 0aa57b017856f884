"""The collision forecast, pure: crossing courses are found before they meet, parallel
and diverging ones are not."""

from __future__ import annotations

import pytest

from server.domain.forecast import Course, forecast
from server.domain.geo import from_local

ORIGIN = (43.9, 15.4)


def course(key: str, x: float, y: float, speed: float, heading: float) -> Course:
    lat, lon = from_local(x, y, *ORIGIN)
    return Course(key, lat, lon, speed, heading)


def test_crossing_courses_are_a_risk_with_the_time_and_distance_of_closest_approach() -> None:
    # a heads east from 100 m west of the crossing, b north from 100 m south: both at 2 m/s.
    a = course("a", -100, 0, 2.0, 90)
    b = course("b", 0, -100, 2.0, 0)
    (risk,) = forecast([a, b], horizon_s=60, separation_m=10)
    assert (risk.a, risk.b) == ("a", "b")
    assert risk.in_s == pytest.approx(50, abs=0.5)
    assert risk.closest_m == pytest.approx(0, abs=0.5)
    assert risk.distance_now_m == pytest.approx(141.4, abs=0.5)
    assert risk.where == pytest.approx(ORIGIN, abs=1e-5)


def test_a_meeting_beyond_the_horizon_is_not_a_risk_yet() -> None:
    a = course("a", -200, 0, 2.0, 90)
    b = course("b", 0, -200, 2.0, 0)
    assert forecast([a, b], horizon_s=60, separation_m=10) == []
    assert len(forecast([a, b], horizon_s=120, separation_m=10)) == 1


@pytest.mark.parametrize(
    ("b", "at_risk"),
    [
        (course("b", 0, 30, 2.0, 90), False),  # side by side, 30 m apart
        (course("b", 0, 8, 2.0, 90), True),  # side by side, 8 m apart
        (course("b", 50, 0, 2.0, 90), False),  # ahead, same speed
        (course("b", 50, 0, 0.5, 90), True),  # ahead and slower: caught up
        (course("b", -50, 0, 2.0, 270), False),  # behind, going away
        (course("b", 5, 0, 0.0, 0), True),  # at rest, 5 m off: within the separation now
    ],
)
def test_pairs(b: Course, at_risk: bool) -> None:
    a = course("a", 0, 0, 2.0, 90)
    assert bool(forecast([a, b], horizon_s=60, separation_m=10)) is at_risk


def test_each_pair_once_among_many() -> None:
    fleet = [course(f"v{k:03d}", 40.0 * (k % 20), 40.0 * (k // 20), 0.0, 0.0) for k in range(400)]
    fleet.append(course("zz", 1.0, 1.0, 0.0, 0.0))  # 1.4 m from v000
    risks = forecast(fleet, horizon_s=60, separation_m=10)
    assert [(r.a, r.b) for r in risks] == [("v000", "zz")]
