"""Boats either side of the antimeridian (longitude 180): near each other, not a world
apart, for the zones' checks, the planner, the collision forecast and the watch. Pure."""

from __future__ import annotations

import pytest
import shapely

from server.domain.forecast import Course, forecast
from server.domain.geo import from_local, haversine_m, to_local, unwrap
from server.domain.plan_frame import Obstacle
from server.domain.planning import plan_path
from server.domain.zones import Area, ZoneSet, breaches, closest_routes, route_violation

WEST_OF_180 = (43.0, 179.999)  # about 80 m west of the antimeridian
EAST_OF_180 = (43.0, -179.999)  # about 80 m east of it


def square(zone_id: str, lat: float, lon: float, half_deg: float, **more: object) -> Area:
    """A square zone round (lat, lon), its ring as a client draws it (longitudes in range)."""
    ring = [
        (lat - half_deg, lon - half_deg),
        (lat - half_deg, lon + half_deg),
        (lat + half_deg, lon + half_deg),
        (lat + half_deg, lon - half_deg),
    ]
    wrapped = tuple((la, (lo + 180) % 360 - 180) for la, lo in [*ring, ring[0]])
    return Area(zone_id, zone_id, more.pop("kind", "no_go"), (wrapped,), **more)  # type: ignore[arg-type]


def test_the_local_frame_takes_the_short_way_round() -> None:
    x, y = to_local(*EAST_OF_180, *WEST_OF_180)
    assert x == pytest.approx(162.6, abs=0.5) and y == 0
    lat, lon = from_local(x, y, *WEST_OF_180)
    assert (lat, lon) == pytest.approx(EAST_OF_180)
    assert unwrap([179.9, -179.9, 179.8]) == pytest.approx([179.9, 180.1, 179.8])


def test_a_zone_half_the_world_away_does_not_refuse_a_step_across_180() -> None:
    """A no-go zone at 0..1 E refused a go_to 160 m east across the antimeridian: the
    way was drawn 359.998 degrees west, over it."""
    far = ZoneSet((square("greenwich", 43.0, 0.5, 0.5),), 1)
    assert route_violation(far, "v", WEST_OF_180, [EAST_OF_180]) is None


def half(zone_id: str, west: float, east: float) -> Area:
    """Half of a reef at 42.9995..43.0005 N, as the API takes a zone across 180: split."""
    ring = ((42.9995, west), (42.9995, east), (43.0005, east), (43.0005, west), (42.9995, west))
    return Area(zone_id, "reef", "no_go", (ring,))


def test_a_zone_split_at_180_holds_its_inside_on_both_sides() -> None:
    reef = ZoneSet((half("w", 179.9995, 180.0), half("e", -180.0, -179.9995)), 1)
    assert breaches(reef, "v", (43.0, 179.9999)) == frozenset({"w"})
    assert breaches(reef, "v", (43.0, -179.9999)) == frozenset({"e"})
    assert breaches(reef, "v", (43.0, -179.99)) == frozenset()
    found = route_violation(reef, "v", (43.0, 179.99), [(43.0, -179.99)])
    assert found is not None and found.message == "the route crosses no-go zone reef"
    into = route_violation(reef, "v", (43.0, 179.99), [(43.0, 179.9999)])  # the west half
    assert into is not None and into.message == "the target is in no-go zone reef"
    assert route_violation(reef, "v", (43.001, 179.99), [(43.001, -179.99)]) is None  # north
    # A zone drawn as one ring across 180 (the API splits it; the check reads it alike).
    whole = ZoneSet((square("reef", 43.0, 180.0, 0.0005),), 1)
    assert whole.areas[0].holds((43.0, 179.9999)) and whole.areas[0].holds((43.0, -179.9999))
    across = route_violation(whole, "v", (43.0, 179.99), [(43.0, -179.99)])
    assert across is not None and across.message == "the route crosses no-go zone reef"


def test_a_zone_on_one_side_holds_a_route_from_the_other() -> None:
    east_reef = ZoneSet((square("reef", 43.0, -179.99, 0.002),), 1)
    found = route_violation(east_reef, "v", (43.0, 179.98), [(43.0, -179.97)])
    assert found is not None and found.zone_id == "reef"
    bay = ZoneSet((square("bay", 43.0, 180.0, 0.01, kind="operating_area", vehicles={"v"}),), 1)
    assert route_violation(bay, "v", WEST_OF_180, [EAST_OF_180]) is None
    assert breaches(bay, "v", EAST_OF_180) == frozenset()
    out = route_violation(bay, "v", WEST_OF_180, [(43.0, -179.98)])
    assert out is not None and "target is outside" in out.message


def test_a_planned_path_across_180_is_short() -> None:
    """Planned round another boat half the world away, the path to a point 160 m east
    went round the globe."""
    path = plan_path(WEST_OF_180, [EAST_OF_180], [Obstacle(43.0, 15.0, 10, "v3")])
    assert path == [EAST_OF_180]
    blocker = Obstacle(43.0, 180.0, 20, "v3")  # on the way, astride the antimeridian
    path = plan_path(WEST_OF_180, [EAST_OF_180], [blocker])
    steps = list(zip([WEST_OF_180, *path], path, strict=False))
    length = sum(haversine_m(*a, *b) for a, b in steps)
    assert 162 < length < 250 and all(-180 <= lon <= 180 for _, lon in path)
    frame = [to_local(*p, *WEST_OF_180) for p in [WEST_OF_180, *path]]
    assert (
        shapely.LineString(frame).distance(shapely.Point(to_local(43.0, 180.0, *WEST_OF_180)))
        >= 19.9
    )


def test_boats_either_side_of_180_heading_for_each_other_are_a_risk() -> None:
    a = Course("a", -30.0, 179.9999, 2.0, 90)
    b = Course("b", -30.0, -179.9999, 2.0, 270)
    (risk,) = forecast([a, b], horizon_s=60, separation_m=10)
    assert risk.distance_now_m == pytest.approx(19.3, abs=0.5)
    assert risk.closest_m == pytest.approx(0, abs=0.5)
    assert -180 <= risk.where[1] <= 180 and abs(abs(risk.where[1]) - 180) < 1e-4
    far = Course("c", -30.0, 0.0, 2.0, 90)  # the fleet spread round the world: still found
    assert [(r.a, r.b) for r in forecast([a, far, b], 60, 10)] == [("a", "b")]


def test_two_routes_either_side_of_180_are_close() -> None:
    west = [(43.0, 179.998), (43.0, 179.99999)]  # up to 1 m short of the antimeridian
    east = [(43.00003, -179.99999), (43.00003, -179.998)]  # from 1 m past it
    found = closest_routes({"a": west, "b": east}, 10.0)
    assert found is not None and found[2] == pytest.approx(3.7, abs=0.3)
