"""A fleet at work across the antimeridian (180°), in a real browser (as test_console_layout):
Leaflet drew 179.999° E and 179.999° W a world apart, a no-go zone split at 180 (as GeoJSON
asks) in two halves at the map's two ends, and a click east of 180 gave a longitude the
server refuses. A world of its own (the module's): two simulated boats, one either side of
180, off Taveuni; ana holds both."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
from playwright.sync_api import expect

from tests.agent.procs import wait_until
from tests.web import console_helpers as console
from tests.web.conftest import Shots, World, served_world

pytestmark = [pytest.mark.slow, pytest.mark.browser]

LAT = -16.8
#: Either side of 180, 0.0003° (about 32 m) from it: Tasman at 179.9997 E (west of the
#: line), Koro at 179.9997 W (east of it).
BOATS = (("tasman", "Tasman", 179.9997), ("koro", "Koro", -179.9997))


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> Iterator[World]:
    boats = [(vehicle_id, name, LAT, lon) for vehicle_id, name, lon in BOATS]
    workdir = tmp_path_factory.mktemp("dateline-server")
    with served_world(workdir, boats, [("ana", "operator")]) as w:
        yield w


def centre(box: dict[str, float]) -> tuple[float, float]:
    return box["x"] + box["width"] / 2, box["y"] + box["height"] / 2


def test_a_fleet_across_180_is_drawn_in_one_piece_and_commanded_across_it(
    world: World, open_console: Any, shots: Shots
) -> None:
    reef = []  # a no-go zone across 180, 300 m north: two polygons split at 180
    for west, east in ((179.999, 180.0), (-180.0, -179.999)):
        corners = [(-16.797, west), (-16.797, east), (-16.796, east), (-16.796, west)]
        body = {
            "name": f"reef {'east' if west > 0 else 'west'}",
            "kind": "no_go",
            "polygon": console.polygon(corners),
        }
        reef.append(world.fleet.call("POST", "/api/zones", json=body)["zone_id"])
    page, _ = open_console()
    console.log_in(page, "ana", markers=2)
    page.locator(".fit-all").click()
    console.next_frames(page)
    view = console.box_of(page.locator("#map"))
    tasman, koro = (console.box_of(console.marker(page, b[0])) for b in BOATS)
    shots(page, "fleet-across-180")
    # both boats on the map, side by side (64 m apart), Koro east of Tasman
    for box in (tasman, koro):
        assert view["x"] <= centre(box)[0] <= view["x"] + view["width"], (box, view)
    assert 0 < centre(koro)[0] - centre(tasman)[0] < 400, (tasman, koro)
    halves = page.locator("path.zone-no_go")
    expect(halves).to_have_count(2)
    a, b = sorted((console.box_of(halves.nth(i)) for i in range(2)), key=lambda r: r["x"])
    assert abs(a["x"] + a["width"] - b["x"]) < 3, (a, b)  # the reef in one piece at 180

    # Tasman sent across 180, 40 px north of Koro: a longitude the server takes
    console.marker(page, "tasman").click()
    page.click('[data-tool="go_to"]')
    x, y = centre(koro)
    page.mouse.click(x, y - 40)
    sent = wait_until(lambda: console.newest_command(world, "tasman", "go_to"), "the go_to")
    assert -180 <= sent["args"]["lon"] < -179.9990, sent["args"]
    expect(console.command_item(page, sent["command_id"])).to_have_attribute(
        "data-stage", "done", timeout=60_000
    )
    here = console.position(world, "tasman")
    assert here["lon"] < 0, here  # it crossed 180
    console.next_frames(page)
    trails = [console.box_of(t) for t in page.locator("path.trail").all()]
    assert trails and all(t["width"] < 400 for t in trails), trails  # not round the world
    shots(page, "crossed-180")

    # the replay draws its track across 180 in one piece, the marker moving the short way
    console.replay_up(page)
    page.click('[data-tab="replay"]')
    page.click('#replay-form [data-minutes="5"]')
    page.click("#replay-load")
    expect(page.locator("#replay-bar")).to_be_visible()
    tracks = [console.box_of(t) for t in page.locator("path.replay-track").all()]
    assert tracks and all(t["width"] < 400 for t in tracks), tracks
    ends = page.evaluate("""() => {
        const r = fleetConsole.replay, m = fleetConsole.map.map;
        return [r.start, (r.start + r.end) / 2, r.end].map((t) => {
            r.seek(t);
            return [...r.markers.values()].map((k) => m.latLngToContainerPoint(k.getLatLng()).x);
        }).flat();
    }""")
    assert max(ends) - min(ends) < 400, ends  # every position on the screen, at every time
    shots(page, "replay-across-180")
    page.click("#replay-exit")
    for zone_id in reef:
        world.fleet.call("DELETE", f"/api/zones/{zone_id}")
