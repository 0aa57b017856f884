"""Where things are on the page, as a field manager's and her operators' test of the console
found them, in a real browser (as test_console_toasts): on a phone the red "LINK LOST"
banner hid behind the replay's, which covered the zoom and layers buttons, the header read
"l…" and "ben · ope…", and the replay's labels ran off the map; on a desktop the toasts
covered the map's controls and swallowed clicks on the map between them, a tab under the
pointer looked selected, and an operating area's name opened at its centre over the boats
wherever the pointer (or, on a phone, a tap) was in it, and the Path tool's bar covered
40 % of a phone's map. A world of its own (the module's):
ana holds every vehicle."""

from __future__ import annotations

from typing import Any

import pytest
from playwright.sync_api import expect

from tests.agent.procs import wait_until
from tests.web import console_helpers as console
from tests.web.conftest import Shots, World

pytestmark = [pytest.mark.slow, pytest.mark.browser]

PHONE = (390, 844)
MAP_CONTROLS = (".leaflet-control-zoom", ".leaflet-control-layers", ".fit-all")

#: The map's banners (the map pane's ::before and ::after) as boxes on the page, with
#: their text and whether it fits whole (its width measured in the banner's font).
BANNERS = """() => {
    const pane = document.getElementById("map-pane");
    const r = pane.getBoundingClientRect();
    const ctx = document.createElement("canvas").getContext("2d");
    return ["::before", "::after"].map((which) => {
        const s = getComputedStyle(pane, which);
        if (s.content === "none" || s.display === "none") return null;
        const text = JSON.parse(s.content);
        ctx.font = `${s.fontWeight} ${s.fontSize} ${s.fontFamily}`;
        const width = parseFloat(s.width);
        return {
            text, fits: ctx.measureText(text).width <= width + 0.5,
            x: r.left + parseFloat(s.left) + parseFloat(s.marginLeft),
            y: r.top + parseFloat(s.top),
            width: width + parseFloat(s.paddingLeft) + parseFloat(s.paddingRight),
            height: parseFloat(s.height),
        };
    }).filter(Boolean);
}"""


def replay_last_minutes(page: Any) -> None:
    page.wait_for_function("() => Boolean(window.fleetConsole && fleetConsole.replay)")
    page.click('[data-tab="replay"]')
    page.click('#replay-form [data-minutes="5"]')
    page.click("#replay-load")
    page.wait_for_function("() => document.getElementById('app').dataset.replay === 'on'")


def whole(page: Any, selector: str) -> bool:
    """Whether the element's text shows whole (nothing cut off or turned into "…")."""
    return bool(page.locator(selector).evaluate("el => el.scrollWidth <= el.clientWidth"))


def test_a_phone_s_banners_stack_clear_of_the_map_s_buttons_and_its_header_reads(
    world: World, open_console: Any, shots: Shots
) -> None:
    page, _ = open_console(viewport=PHONE)
    console.log_in(page, "ben")
    link, who = page.locator("#link"), page.locator("#who")
    replay_last_minutes(page)
    page.click('[data-tab="map"]')
    page.context.set_offline(True)  # a phone out of signal: found within 25 s
    expect(link).to_have_attribute("data-state", "lost", timeout=35_000)
    shots(page, "phone-lost-in-replay")

    # read while the link is lost (between two tries to reconnect it is "connecting")
    banners = page.wait_for_function(
        f"() => document.getElementById('app').dataset.link === 'lost' && ({BANNERS})()"
    ).json_value()
    assert [b["text"] for b in banners] == [
        "LINK LOST: positions may be old",
        "REPLAY: recorded positions, not live",
    ]
    lost, replay = banners
    assert all(b["fits"] for b in banners), banners
    assert not console.boxes_overlap(lost, replay), banners
    assert lost["y"] < replay["y"]  # the link's first
    for selector in MAP_CONTROLS:
        control = console.box_of(page.locator(selector))
        for banner in banners:
            assert not console.boxes_overlap(banner, control), (selector, banner, control)

    # the header says the link's state and who is logged in whole, lost or live
    expect(link).to_contain_text("link lost")
    assert whole(page, "#link") and whole(page, "#who"), (link.inner_text(), who.inner_text())
    assert who.inner_text() == "ben"  # the role gives way, the name stays whole
    assert page.evaluate("document.documentElement.scrollWidth") <= PHONE[0]
    page.context.set_offline(False)
    expect(link).to_have_attribute("data-state", "live", timeout=30_000)
    expect(link).to_have_text("live")
    assert whole(page, "#link") and whole(page, "#who"), (link.inner_text(), who.inner_text())
    shots(page, "phone-live-header")


def test_a_phone_s_replay_labels_stay_on_the_map(
    world: World, open_console: Any, shots: Shots
) -> None:
    """Live labels switch sides at the map's edge; the replay's ran off it."""
    page, _ = open_console(viewport=PHONE)
    console.log_in(page, "ana")
    replay_last_minutes(page)
    page.click('[data-tab="map"]')
    label = page.locator('.vicon.replay[data-vehicle="demo-usv-1"] .vlabel')
    expect(label).to_be_visible()
    view = console.box_of(page.locator("#map"))
    icon = console.box_of(page.locator('.vicon.replay[data-vehicle="demo-usv-1"]'))
    to_edge = view["x"] + view["width"] - 30 - (icon["x"] + icon["width"] / 2)
    page.evaluate(  # the marker 30 px from the map's right edge
        "(dx) => fleetConsole.map.map.panBy([-dx, 0], {animate: false})", to_edge
    )
    console.next_frames(page)
    box = console.box_of(label)
    shots(page, "replay-label-at-the-edge")
    assert box["x"] >= view["x"] and box["x"] + box["width"] <= view["x"] + view["width"], (
        box,
        view,
    )


def test_toasts_leave_the_map_s_controls_and_clicks_to_it(
    world: World, open_console: Any, shots: Shots
) -> None:
    """On a desktop the toasts' column covered All boats and the scale and grid's note, and
    a click on the map beside or between toasts was lost (a path's waypoint missed)."""
    page, _ = open_console()
    console.log_in(page, "mia")
    console.marker(page, "demo-usv-1").click()
    page.click('#actions [data-tool="path"]')
    for vehicle_id in console.ALL:  # three toasts for the manager
        body = {"instance_id": world.instances[vehicle_id]}
        world.as_user("ben", "POST", "/client/request_control", json=body)
    shown = page.locator("#toasts .toast")
    expect(shown).to_have_count(3)
    shots(page, "three-toasts")
    area = console.box_of(page.locator("#toasts"))
    for control in page.locator(".leaflet-control").all():
        if control.is_visible():
            box = console.box_of(control)
            assert not console.boxes_overlap(area, box), (control.inner_text(), area, box)
    # a click on the map between two toasts is a click on the map: a waypoint
    first, second = console.box_of(shown.nth(0)), console.box_of(shown.nth(1))
    x = first["x"] + first["width"] / 2
    y = (first["y"] + first["height"] + second["y"]) / 2
    page.mouse.click(x, y)
    expect(page.locator("#path-count")).to_have_text("1 waypoint")
    page.click("#path-cancel")


def test_a_tab_under_the_pointer_does_not_look_selected(
    world: World, open_console: Any, shots: Shots
) -> None:
    page, _ = open_console()
    console.log_in(page, "ana")
    selected = page.locator('.tabs [aria-selected="true"]')
    other = page.locator('.tabs [data-tab="control"]')
    expect(other).to_have_attribute("aria-selected", "false")
    other.hover()
    shots(page, "tab-hovered")
    underline = "el => getComputedStyle(el).borderBottomColor"
    assert other.evaluate(underline) != selected.evaluate(underline)


def operating_area(world: World) -> tuple[dict[str, float], str]:
    """An operating area round the three boats with some 400 m of water beyond them on
    every side, as a field manager adds one: its bounds (south, west, north, east) and its
    id."""
    here = [console.position(world, v) for v in console.ALL]
    box = {
        "south": min(p["lat"] for p in here) - 0.004,
        "north": max(p["lat"] for p in here) + 0.004,
        "west": min(p["lon"] for p in here) - 0.005,
        "east": max(p["lon"] for p in here) + 0.005,
    }
    ring = [
        [box["west"], box["south"]],
        [box["east"], box["south"]],
        [box["east"], box["north"]],
        [box["west"], box["north"]],
        [box["west"], box["south"]],
    ]
    body = {
        "name": "bay",
        "kind": "operating_area",
        "vehicles": list(console.ALL),
        "polygon": {"type": "Polygon", "coordinates": [ring]},
    }
    return box, world.fleet.call("POST", "/api/zones", json=body)["zone_id"]


def tooltip_over_boats(page: Any, tip: dict[str, float]) -> list[str]:
    """The boats whose marker or label the tooltip's box covers."""
    covered = []
    for vehicle_id in console.ALL:
        for part in (
            console.marker(page, vehicle_id),
            console.marker(page, vehicle_id).locator(".vlabel"),
        ):
            if console.boxes_overlap(tip, console.box_of(part)):
                covered.append(vehicle_id)
    return covered


def test_an_operating_area_s_name_shows_on_its_outline_not_over_the_boats(
    world: World, open_console: Any, shots: Shots
) -> None:
    """With an operating area round the working area, the pointer anywhere over the map
    opened "bay: operating area (...)" at the area's centre, and it stayed there as long as
    the pointer was inside (almost always), over a boat's trail. It shows now only with
    the pointer on or near the outline, beside the pointer, and goes when it leaves."""
    box, zone_id = operating_area(world)
    try:
        page, _ = open_console()
        console.log_in(page, "ana")
        expect(page.locator("path.zone-operating_area")).to_have_count(1)
        middle = (box["south"] + box["north"]) / 2
        console.centre_on(page, middle, (box["west"] + box["east"]) / 2, 16)
        tooltip = page.locator(".leaflet-tooltip")
        # the pointer over the water inside the area, and by each boat
        inside = [(middle, box["west"] + 0.002), (box["north"] - 0.002, box["east"] - 0.003)]
        for vehicle_id in console.ALL:
            p = console.position(world, vehicle_id)
            inside.append((p["lat"] - 0.0004, p["lon"]))
        for lat, lon in inside:
            page.mouse.move(*console.screen_point(page, lat, lon))
            console.next_frames(page)
            shots(page, "pointer-inside")
            assert tooltip.count() == 0, f"a tooltip at {lat}, {lon}: {tooltip.all_inner_texts()}"
        # on the outline (low on its west side, away from the boats): the area's name,
        # beside the pointer and on the map
        x, y = console.screen_point(page, box["south"] + 0.0012, box["west"])
        page.mouse.move(x, y)
        expect(tooltip).to_have_text("bay: operating area (demo-usv-1, demo-usv-2, demo-usv-3)")
        shots(page, "pointer-on-the-outline")
        tip, view = console.box_of(tooltip), console.box_of(page.locator("#map"))
        assert tip["x"] - 30 <= x <= tip["x"] + tip["width"] + 30, (x, tip)
        assert tip["y"] - 30 <= y <= tip["y"] + tip["height"] + 30, (y, tip)
        assert view["x"] <= tip["x"] and tip["x"] + tip["width"] <= view["x"] + view["width"]
        assert tooltip_over_boats(page, tip) == []
        page.mouse.move(*console.screen_point(page, middle, box["west"] + 0.002))
        expect(tooltip).to_have_count(0)

        # a no-go zone the same: its name on its outline, nothing inside it
        south, west = box["north"] - 0.0025, box["east"] - 0.0035
        ring = [[west, south], [west + 0.002, south], [west + 0.002, south + 0.0015]]
        body = {
            "name": "rocks",
            "kind": "no_go",
            "polygon": {
                "type": "Polygon",
                "coordinates": [[*ring, [west, south + 0.0015], ring[0]]],
            },
        }
        rocks = world.fleet.call("POST", "/api/zones", json=body)["zone_id"]
        expect(page.locator("path.zone-no_go")).to_have_count(1)
        page.mouse.move(*console.screen_point(page, south + 0.00075, west + 0.001))
        console.next_frames(page)
        assert tooltip.count() == 0, tooltip.all_inner_texts()
        page.mouse.move(*console.screen_point(page, south + 0.00075, west))
        expect(tooltip).to_have_text("rocks: no-go zone")
        shots(page, "no-go-outline")
        world.fleet.call("DELETE", f"/api/zones/{rocks}")
    finally:
        world.fleet.call("DELETE", f"/api/zones/{zone_id}")


def test_a_tap_in_an_operating_area_on_a_phone_opens_nothing(
    world: World, open_console: Any, shots: Shots
) -> None:
    """On a phone one tap anywhere in the area opened its tooltip, cut off at the map's
    left edge and over a boat's marker and name. A tap inside opens nothing now; a tap on
    the outline by the map's edge shows the name whole, on the map and clear of the boats."""
    box, zone_id = operating_area(world)
    try:
        page, _ = open_console(viewport=PHONE, is_mobile=True, has_touch=True)
        console.log_in(page, "ana")
        expect(page.locator("path.zone-operating_area")).to_have_count(1)
        middle = (box["south"] + box["north"]) / 2
        console.centre_on(page, middle, (box["west"] + box["east"]) / 2, 16)
        tooltip = page.locator(".leaflet-tooltip")
        near = console.position(world, "demo-usv-1")
        page.touchscreen.tap(*console.screen_point(page, near["lat"] - 0.0004, near["lon"]))
        console.next_frames(page)
        shots(page, "tapped-inside")
        assert tooltip.count() == 0, tooltip.all_inner_texts()
        # the area's west side 6 px from the map's left edge, tapped low in the area
        view = console.box_of(page.locator("#map"))
        x, _ = console.screen_point(page, middle, box["west"])
        page.evaluate(
            "(dx) => fleetConsole.map.map.panBy([dx, 0], {animate: false})", x - view["x"] - 6
        )
        console.next_frames(page)
        low = box["south"] + 0.0012
        page.touchscreen.tap(*console.screen_point(page, low, box["west"]))
        expect(tooltip).to_contain_text("bay: operating area")
        console.next_frames(page)  # and stays (a finger has no hover to leave)
        expect(tooltip).to_be_visible()
        shots(page, "tapped-the-outline")
        tip = console.box_of(tooltip)
        assert view["x"] <= tip["x"] and tip["x"] + tip["width"] <= view["x"] + view["width"], (
            tip,
            view,
        )
        assert tooltip_over_boats(page, tip) == []
        # a tap on the map elsewhere puts it away
        page.touchscreen.tap(*console.screen_point(page, middle, box["west"] + 0.002))
        expect(tooltip).to_have_count(0)
    finally:
        world.fleet.call("DELETE", f"/api/zones/{zone_id}")


def test_a_phone_s_path_tool_leaves_the_map_to_tap(
    world: World, open_console: Any, shots: Shots
) -> None:
    """The Path tool armed on a phone: the action bar took 40 % of the map (every tool,
    both options, the path's row), and a waypoint tapped low on the map landed on it. It
    keeps the path's row, the speed and Stop; a tap just above it adds a waypoint; Cancel
    brings the other tools back."""
    page, _ = open_console(viewport=PHONE, is_mobile=True, has_touch=True)
    console.log_in(page, "ana")
    expect(page.locator("#map")).to_be_visible()
    console.marker(page, "demo-usv-1").tap()
    actions = page.locator("#actions")
    for tool in ("go_to", "station"):
        expect(actions.locator(f'[data-tool="{tool}"]')).to_be_visible()
    page.locator('[data-tool="path"]').tap()
    expect(page.locator("#path-bar")).to_be_visible()
    console.next_frames(page)
    shots(page, "phone-path-tool")
    view, bar = console.box_of(page.locator("#map")), console.box_of(actions)
    assert bar["height"] <= 0.32 * view["height"], (bar, view)
    for hidden in ('[data-tool="go_to"]', '[data-tool="station"]', "#hold", "#opt-radius"):
        expect(actions.locator(hidden)).to_be_hidden()
    for shown in ("#path-send", "#path-undo", "#path-cancel", "#stop-selected", "#opt-speed"):
        expect(actions.locator(shown)).to_be_visible()
    page.touchscreen.tap(view["x"] + view["width"] / 2, bar["y"] - 12)
    expect(page.locator("#path-count")).to_have_text("1 waypoint")
    page.locator("#path-cancel").tap()
    expect(page.locator("#path-bar")).to_be_hidden()
    for tool in ("go_to", "path", "station"):
        expect(actions.locator(f'[data-tool="{tool}"]')).to_be_visible()
    expect(actions.locator("#opt-radius")).to_be_visible()


def test_a_small_station_circle_is_not_hidden_under_a_label(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A keep-station circle a few pixels wide lay under another boat's name, where that
    name goes first (to the right of its marker): the label goes elsewhere."""
    page, _ = open_console()
    console.log_in(page, "ana")
    expect(page.locator("#map")).to_be_visible()
    bravo = console.position(world, "demo-usv-2")
    console.centre_on(page, bravo["lat"], bravo["lon"], 19)
    label = page.locator('.vicon:not(.replay)[data-vehicle="demo-usv-2"] .vlabel')
    right = console.box_of(label)  # where Bravo's name is with nothing to keep clear of
    marker = console.box_of(console.marker(page, "demo-usv-2"))
    assert right["x"] > marker["x"] + marker["width"] / 2, (right, marker)
    # Alpha told to keep station 3 m across under the middle of Bravo's name
    view = console.box_of(page.locator("#map"))
    middle = [
        right["x"] + right["width"] / 2 - view["x"],
        right["y"] + right["height"] / 2 - view["y"],
    ]
    at = page.evaluate(
        "p => { const c = fleetConsole.map.map.containerPointToLatLng(p); return [c.lat, c.lng]; }",
        middle,
    )
    command = {"type": "keep_station", "args": {"lat": at[0], "lon": at[1], "radius_m": 1.5}}
    world.as_user(
        "ana", "POST", "/client/submit_control",
        json={"instance_ids": [world.instances["demo-usv-1"]], "command": command},
    )  # fmt: skip
    circle = page.locator("path.station")
    expect(circle).to_have_count(1)

    def clear() -> bool:
        ring, name = circle.bounding_box(), label.bounding_box()
        return bool(ring and name and not console.boxes_overlap(ring, name))

    wait_until(clear, "Bravo's name clear of the station circle", 10)
    shots(page, "station-clear-of-labels")
