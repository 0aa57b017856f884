"""The failsafe's side on the server, pure: the command a zone breach sends, where home
may be, and how a breached zone is named."""

from __future__ import annotations

import pytest

from fleet_protocol import FailsafePolicy
from fleet_protocol.common import LatLon
from server.domain.failsafe import breach_command, check_home
from server.domain.geo import from_local
from server.domain.watch import breach_data
from server.domain.zones import Area, ZoneSet
from server.errors import ZoneViolation

ORIGIN = (43.9, 15.4)
BOTH = ["keep_station", "go_to", "stop"]


def at(x: float, y: float) -> tuple[float, float]:
    return from_local(x, y, *ORIGIN)


def square(
    zone_id: str, x: float, y: float, side: float, kind: str = "no_go", vehicles: str = ""
) -> Area:
    """A square zone ``side`` m wide, its south-west corner ``(x, y)`` m from the origin;
    its name is ``zone_id`` in capitals."""
    corners = [(x, y), (x + side, y), (x + side, y + side), (x, y + side), (x, y)]
    ring = tuple(at(cx, cy) for cx, cy in corners)
    return Area(zone_id, zone_id.upper(), kind, (ring,), frozenset(vehicles.split()))  # type: ignore[arg-type]


#: A no-go zone 100 m wide, 100 m to 200 m east of the origin.
ZONES = ZoneSet((square("rock", 100, -50, 100),), version=1)
HERE = {"lat": at(0, 0)[0], "lon": at(0, 0)[1]}


def policy(action: str, home: tuple[float, float] | None = None) -> FailsafePolicy:
    where = LatLon(lat=home[0], lon=home[1]) if home is not None else None
    return FailsafePolicy(action=action, home=where, on_breach=True)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("action", "capabilities", "sent"),
    [
        ("stop", BOTH, "stop"),
        ("keep_station", BOTH, "keep_station"),
        ("keep_station", ["go_to", "stop"], "stop"),  # what it cannot do is a stop
    ],
)
def test_an_action_without_a_way_is_sent_as_it_is(
    action: str, capabilities: list[str], sent: str
) -> None:
    assert breach_command(policy(action), ZONES, "v", capabilities, HERE, None) == (sent, {})


def test_return_home_on_a_clear_way_is_held_there_or_driven_to() -> None:
    home = at(-100, 0)
    args = {"lat": home[0], "lon": home[1]}
    assert breach_command(policy("return_home", home), ZONES, "v", BOTH, HERE, None) == (
        "keep_station",
        args,
    )
    only_go = ["go_to", "stop"]
    assert breach_command(policy("return_home"), ZONES, "v", only_go, HERE, home) == (
        "go_to",
        args,
    )


def test_return_home_through_a_no_go_zone_or_to_no_home_keeps_station() -> None:
    behind_the_rock = policy("return_home", at(300, 0))
    assert breach_command(behind_the_rock, ZONES, "v", BOTH, HERE, None) == ("keep_station", {})
    assert breach_command(policy("return_home"), ZONES, "v", BOTH, HERE, None) == (
        "keep_station",
        {},
    )


def test_a_home_in_a_no_go_zone_is_refused_naming_home() -> None:
    check_home(ZONES, "v", at(-100, 0))
    with pytest.raises(ZoneViolation) as refused:
        check_home(ZONES, "v", at(150, 0))
    assert refused.value.message == "the failsafe's home is in no-go zone ROCK"
    assert refused.value.details[0]["field"] == "home"
    assert refused.value.details[0]["zone_id"] == "rock"


def test_a_breach_names_its_zone_or_the_vehicles_operating_areas() -> None:
    assert breach_data(ZONES, "v", "rock", entered=True) == {
        "zone_id": "rock",
        "zone": "ROCK",
        "zone_kind": "no_go",
        "message": "entered no-go zone ROCK",
    }
    assert breach_data(ZONES, "v", "gone", entered=False)["message"] == "left no-go zone gone"
    pen = square("pen", -500, -500, 1000, "operating_area", vehicles="v")
    areas = ZoneSet((pen,), version=2)
    assert breach_data(areas, "v", "area:v", entered=True) == {
        "zone_id": "pen",
        "zone": "PEN",
        "zone_kind": "operating_area",
        "message": "left its operating area",
    }
    assert breach_data(areas, "w", "area:w", entered=False) == {
        "zone_id": None,  # w has no operating area of its own
        "zone": "",
        "zone_kind": "operating_area",
        "message": "back in its operating area",
    }
