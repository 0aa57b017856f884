"""Track downsampling (Visvalingam-Whyatt) and the page cut."""

from __future__ import annotations

import itertools
import math
from datetime import UTC, datetime, timedelta

import pytest
from hypothesis import given
from hypothesis import strategies as st

from server.domain.track import cut_page, simplify

T0 = datetime(2026, 11, 22, 10, 0, 0, tzinfo=UTC)


def square_track(per_side: int) -> tuple[list[float], list[float]]:
    """A closed-ish square path with many collinear points on each side."""
    corners = [(0.0, 0.0), (0.0, 0.01), (0.01, 0.01), (0.01, 0.0), (0.0, 0.0)]
    lat: list[float] = []
    lon: list[float] = []
    for (a_lat, a_lon), (b_lat, b_lon) in itertools.pairwise(corners):
        for k in range(per_side):
            f = k / per_side
            lat.append(60 + a_lat + (b_lat - a_lat) * f)
            lon.append(10 + a_lon + (b_lon - a_lon) * f)
    lat.append(60.0)
    lon.append(10.0)
    return lat, lon


def test_keeps_everything_when_under_the_limit() -> None:
    assert simplify([1.0, 2.0, 3.0], [1.0, 2.0, 3.0], 10) == [0, 1, 2]
    assert simplify([], [], 5) == []
    assert simplify([1.0], [1.0], 1) == [0]


def test_returns_exactly_max_points_with_first_and_last() -> None:
    lat = [60 + 0.001 * math.sin(i / 7) for i in range(1000)]
    lon = [10 + 0.0001 * i for i in range(1000)]
    kept = simplify(lat, lon, 50)
    assert len(kept) == 50
    assert kept[0] == 0 and kept[-1] == 999
    assert kept == sorted(kept)


def test_square_reduces_to_its_corners() -> None:
    lat, lon = square_track(25)
    kept = simplify(lat, lon, 5)
    corners = {(round(lat[i], 6), round(lon[i], 6)) for i in kept}
    assert corners == {(60.0, 10.0), (60.0, 10.01), (60.01, 10.01), (60.01, 10.0)}


@pytest.mark.parametrize("moving", [True, False])
def test_a_straight_run_or_a_vehicle_at_rest_keeps_points_spread_along_it(moving: bool) -> None:
    """All areas zero: what is kept is spread over the whole track (it piled up at its end:
    of 4 hours, 96 of 100 points in the last 96 s)."""
    n, keep = 15_000, 100
    lat = [60 + (1e-6 * i if moving else 0.0) for i in range(n)]
    lon = [10.0] * n
    kept = simplify(lat, lon, keep)
    assert len(kept) == keep and kept[0] == 0 and kept[-1] == n - 1
    gaps = [b - a for a, b in itertools.pairwise(kept)]
    assert max(gaps) <= 2 * n / (keep - 1), max(gaps)


def test_a_square_keeps_its_corners_and_points_between_them() -> None:
    lat, lon = square_track(1000)
    kept = simplify(lat, lon, 40)
    for corner in (0, 1000, 2000, 3000, 4000):
        assert corner in kept
    assert max(b - a for a, b in itertools.pairwise(kept)) <= 250


def test_a_sharp_spike_survives_while_noise_goes() -> None:
    n = 500
    lat = [60.0 + (1e-7 if i % 2 else 0.0) for i in range(n)]
    lon = [10 + 1e-5 * i for i in range(n)]
    lat[250] = 60.05  # one excursion far off the line
    kept = simplify(lat, lon, 5)
    assert 250 in kept


def test_below_two_points_acts_as_two() -> None:
    assert simplify([1.0, 2.0, 3.0, 4.0], [0.0, 1.0, 0.0, 1.0], 0) == [0, 3]


def test_across_the_antimeridian_the_shape_is_kept() -> None:
    # A straight eastward run over 180° and one corner: the corner must stay.
    lon = [179.990 + 0.001 * i for i in range(20)]
    lon = [x - 360 if x > 180 else x for x in lon]
    lat = [0.0] * 20 + [0.001 * k for k in range(1, 20)]
    lon = lon + [lon[-1]] * 19
    kept = simplify(lat, lon, 3)
    assert kept == [0, 19, 38]


def test_mismatched_lengths_are_refused() -> None:
    with pytest.raises(ValueError):
        simplify([1.0, 2.0], [1.0], 2)


@given(
    st.lists(st.tuples(st.floats(-80, 80), st.floats(-179, 179)), min_size=0, max_size=200),
    st.integers(min_value=0, max_value=250),
)
def test_properties(points: list[tuple[float, float]], max_points: int) -> None:
    lat = [p[0] for p in points]
    lon = [p[1] for p in points]
    kept = simplify(lat, lon, max_points)
    n = len(points)
    assert kept == sorted(set(kept))
    assert len(kept) == min(n, max(max_points, 2))
    if n:
        assert kept[0] == 0 and kept[-1] == n - 1


def test_cut_page_fits() -> None:
    times = [T0 + timedelta(seconds=i) for i in range(5)]
    assert cut_page(times, 5) == (5, None)
    assert cut_page([], 5) == (0, None)


def test_cut_page_cuts_at_the_next_point() -> None:
    times = [T0 + timedelta(seconds=i) for i in range(10)]
    assert cut_page(times, 4) == (4, T0 + timedelta(seconds=4))


def test_cut_page_never_splits_a_timestamp() -> None:
    times = [T0, T0, T0 + timedelta(seconds=1), T0 + timedelta(seconds=1), T0 + timedelta(2)]
    count, next_from = cut_page(times, 3)
    assert (count, next_from) == (2, T0 + timedelta(seconds=1))


def test_cut_page_when_one_timestamp_overflows() -> None:
    times = [T0] * 6
    assert cut_page(times, 4) == (4, T0 + timedelta(milliseconds=1))
