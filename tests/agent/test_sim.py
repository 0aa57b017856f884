"""The simulator's dynamics and guidance, stepped without any clock."""

from __future__ import annotations

import itertools
import math

import pytest

from vehicle_client.geo import LocalFrame, distance_m, heading_deg, wrap_deg
from vehicle_client.sim import Current, Simulator, VehicleParams, VehicleState, step
from vehicle_client.sim.tasks import water_command

BIOGRAD = (43.94, 15.44)


def make_sim(current: Current | None = None, **params: float) -> Simulator:
    return Simulator(*BIOGRAD, params=VehicleParams(**params), current=current)


def latlon(sim: Simulator, east: float, north: float) -> dict[str, float]:
    lat, lon = sim.frame.to_latlon(east, north)
    return {"lat": lat, "lon": lon}


def run_until_final(sim: Simulator, limit_s: float, dt: float = 0.5):
    report = None
    t = 0.0
    while t < limit_s:
        report = sim.step(dt)
        t += dt
        if report is not None and report.status != "executing":
            return report
    raise AssertionError(f"task still {report} after {limit_s} s")


def test_local_frame_round_trip_and_distance() -> None:
    frame = LocalFrame(*BIOGRAD)
    lat, lon = frame.to_latlon(300.0, -400.0)
    east, north = frame.to_enu(lat, lon)
    assert east == pytest.approx(300.0, abs=1e-6)
    assert north == pytest.approx(-400.0, abs=1e-6)
    assert distance_m(*BIOGRAD, lat, lon) == pytest.approx(500.0, rel=1e-3)


def test_compass_angles() -> None:
    assert heading_deg(1.0, 0.0) == pytest.approx(90.0)
    assert heading_deg(0.0, -1.0) == pytest.approx(180.0)
    assert wrap_deg(350.0 - 10.0) == pytest.approx(-20.0)


def test_speed_saturates_at_top_speed() -> None:
    state, params = VehicleState(), VehicleParams(max_speed_mps=0.5)
    for _ in range(200):
        state = step(state, params, 5.0, 5.0, None, Current(), 0.1)
    assert state.water_speed_mps == pytest.approx(0.5)


def test_current_drifts_a_hull_without_thrust() -> None:
    sim = make_sim(Current.from_speed(0.2, 90.0))
    sim.step(100.0)
    assert sim.state.east == pytest.approx(20.0, rel=1e-6)
    assert sim.state.north == pytest.approx(0.0, abs=1e-9)


def test_battery_drains_faster_under_thrust() -> None:
    idle, working = make_sim(), make_sim()
    working.start(working.task_for("go_to", latlon(working, 10_000.0, 0.0)))
    idle.step(600.0)
    working.step(600.0)
    assert 100.0 > idle.state.battery_pct > working.state.battery_pct


def test_empty_battery_gives_no_thrust() -> None:
    sim = make_sim()
    sim.drain(0.0)
    sim.start(sim.task_for("go_to", latlon(sim, 100.0, 0.0)))
    sim.step(60.0)
    assert sim.state.water_speed_mps == 0.0


def test_water_command_crabs_to_hold_the_line() -> None:
    current = (0.0, 0.3)  # northwards
    we, wn = water_command(1.0, 0.0, 0.3, current, 0.5)
    assert math.hypot(we, wn) <= 0.5 + 1e-9
    assert wn + current[1] == pytest.approx(0.0, abs=1e-9)  # no northward ground drift
    assert we == pytest.approx(0.3)


@pytest.mark.parametrize("current", [Current(), Current.from_speed(0.2, 45.0)])
def test_go_to_arrives_within_one_metre_and_reports_done(current: Current) -> None:
    sim = make_sim(current)
    target = latlon(sim, 40.0, -30.0)
    sim.start(sim.task_for("go_to", target))
    report = run_until_final(sim, 600.0)
    assert report.kind == "go_to" and report.status == "done"
    assert sim.distance_to(target["lat"], target["lon"]) <= 1.0


def test_a_boat_sent_across_the_antimeridian_goes_the_short_way_and_stays_in_range() -> None:
    """179.9998 E to 179.9998 W is about 40 m east across 180, not 40,000 km west round the
    globe; every position it reports has a longitude the wire takes (east of 180 it is
    west: -179.99..., never 180.0001)."""
    sim = Simulator(-16.8, 179.9998)
    target = {"lat": -16.8, "lon": -179.9998}
    assert sim.distance_to(target["lat"], target["lon"]) == pytest.approx(42.6, abs=0.5)
    sim.start(sim.task_for("go_to", target))
    report, lons = None, []
    for _ in range(1200):
        report = sim.step(0.5)
        lons.append(sim.position[1])
        if report is not None and report.status != "executing":
            break
    assert report is not None and report.status == "done", report
    assert all(-180.0 <= lon <= 180.0 for lon in lons), max(lons)
    assert min(lons) < -179.9990 and max(lons) > 179.9990  # it crossed 180
    assert sim.distance_to(target["lat"], target["lon"]) <= 1.0


def test_keep_station_holds_against_a_current_that_would_carry_it_away() -> None:
    current = Current.from_speed(0.3, 200.0)
    held, drifting = make_sim(current), make_sim(current)
    held.start(held.task_for("keep_station", {"radius_m": 2.0}))
    worst = 0.0
    for _ in range(1200):  # ten minutes
        report = held.step(0.5)
        drifting.step(0.5)
        worst = max(worst, math.hypot(held.state.east, held.state.north))
    assert report is not None and report.status == "executing"
    assert worst <= 2.0
    assert math.hypot(drifting.state.east, drifting.state.north) > 100.0


def test_keep_station_at_a_given_point_goes_there_first() -> None:
    sim = make_sim(Current.from_speed(0.1, 0.0))
    sim.start(sim.task_for("keep_station", {**latlon(sim, 20.0, 0.0), "radius_m": 3.0}))
    sim.step(300.0)
    assert math.hypot(sim.state.east - 20.0, sim.state.north) <= 3.0


def test_follow_path_passes_every_waypoint_with_rising_progress() -> None:
    sim = make_sim(Current.from_speed(0.15, 90.0))
    legs = [(30.0, 0.0), (30.0, 30.0), (0.0, 30.0)]
    sim.start(sim.task_for("follow_path", {"waypoints": [latlon(sim, *p) for p in legs]}))
    closest = [math.inf] * len(legs)
    progress = [0.0]
    report = None
    for _ in range(4000):
        report = sim.step(0.5)
        for i, (e, n) in enumerate(legs):
            closest[i] = min(closest[i], math.hypot(sim.state.east - e, sim.state.north - n))
        if report.progress is not None:
            progress.append(report.progress)
        if report.status != "executing":
            break
    assert report is not None and report.status == "done"
    assert progress[-1] == 1.0
    assert all(b >= a - 0.02 for a, b in itertools.pairwise(progress))
    assert closest[0] <= 3.0 and closest[1] <= 3.0 and closest[2] <= 1.0


def test_follow_path_stays_near_the_line() -> None:
    sim = make_sim(Current.from_speed(0.2, 0.0))  # pushes off an eastward leg
    sim.start(sim.task_for("follow_path", {"waypoints": [latlon(sim, 80.0, 0.0)]}))
    worst = 0.0
    while (report := sim.step(0.5)).status == "executing":
        worst = max(worst, abs(sim.state.north))
    assert report.status == "done"
    assert worst < 1.5


def test_follow_path_prefers_the_planned_path() -> None:
    sim = make_sim()
    args = {"waypoints": [latlon(sim, 10.0, 0.0)], "path": [latlon(sim, 0.0, 10.0)]}
    sim.start(sim.task_for("follow_path", args))
    run_until_final(sim, 300.0)
    assert math.hypot(sim.state.east, sim.state.north - 10.0) <= 1.0


def test_stop_brings_the_hull_to_rest_in_the_water() -> None:
    sim = make_sim()
    sim.start(sim.task_for("go_to", latlon(sim, 100.0, 0.0)))
    sim.step(20.0)
    assert sim.state.water_speed_mps > 0.4
    sim.start(sim.task_for("stop", {}))
    report = run_until_final(sim, 30.0)
    assert report.status == "done" and sim.state.water_speed_mps < 0.02


def test_long_step_equals_many_short_ones() -> None:
    a, b = make_sim(Current(0.1, 0.0)), make_sim(Current(0.1, 0.0))
    for sim in (a, b):
        sim.start(sim.task_for("go_to", latlon(sim, 50.0, 50.0)))
    a.step(20.0)
    for _ in range(200):
        b.step(0.1)
    assert a.state.east == pytest.approx(b.state.east, abs=1e-6)
    assert a.state.north == pytest.approx(b.state.north, abs=1e-6)


def test_unknown_command_type_is_refused() -> None:
    with pytest.raises(ValueError, match="cannot execute"):
        make_sim().task_for("dive", {})
