"""Commanding from the console (``/``), in headless chromium against a real server with the
demo's three simulated vehicles: select a vehicle and send it where the map is clicked
(go to, keep station, Hold here for two), draw a path the server plans round an
obstacle, and stop one vehicle or all only once confirmed. Screenshots: one per step, in
each test's output folder (and ``$FLEET_WEB_SHOTS``); ``FLEET_README_SHOT=1`` also writes
the README's picture, ``docs/img/dashboard.png``.

A world of its own (the module's), in file order: ana holds every vehicle at the start.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import pytest
from playwright.sync_api import expect

from tests.agent.procs import wait_until
from tests.web import console_helpers as console
from tests.web.conftest import Shots, World, no_requests
from vehicle_client.geo import LocalFrame, distance_m

pytestmark = [pytest.mark.slow, pytest.mark.browser]

ROOT = Path(__file__).resolve().parents[2]
README_SHOT = ROOT / "docs" / "img" / "dashboard.png"


def test_select_a_vehicle_and_send_go_to_by_clicking_the_map(
    world: World, open_console: Any, shots: Shots
) -> None:
    page, guard = open_console()
    console.log_in(page, "ana")
    start = console.position(world, "demo-usv-1")
    console.centre_on(page, start["lat"], start["lon"], 19)
    console.marker(page, "demo-usv-1").click()
    expect(console.marker(page, "demo-usv-1")).to_have_class(re.compile(r"\bselected\b"))
    expect(page.locator("#actions")).to_be_visible()
    expect(page.locator("#vehicle-pane h2")).to_contain_text("H2OmniX Alpha")
    shots(page, "selected")

    target = LocalFrame(start["lat"], start["lon"]).to_latlon(6.0, 10.0)  # 10 m north, 6 m east
    page.click('[data-tool="go_to"]')
    expect(page.locator("#tool-hint")).to_be_visible()
    x, y = console.screen_point(page, *target)
    page.mouse.click(x, y)
    sent = wait_until(
        lambda: console.newest_command(world, "demo-usv-1", "go_to"), "the go_to stored"
    )
    assert distance_m(sent["args"]["lat"], sent["args"]["lon"], *target) < 0.5  # where clicked
    assert sent["issued_by"] == "ana"
    item = console.command_item(page, sent["command_id"])
    expect(item).to_be_visible()
    shots(page, "go-to-sent")

    # its life shows beside the vehicle and in the panel: delivered, acked, ..., done
    expect(item).to_have_attribute("data-stage", "done", timeout=60_000)
    steps = item.locator(".steps").inner_text()
    assert steps.split(" → ")[:2] == ["queued", "delivered"], steps
    assert steps.endswith("done") and "acked" in steps, steps
    expect(console.marker(page, "demo-usv-1").locator(".chip")).to_have_text("go to · done")
    assert world.fleet.command(sent["command_id"])["status"] == "done"
    shots(page, "go-to-done")

    # keep station where the map is clicked, 4 m south of where it arrived
    here = console.position(world, "demo-usv-1")
    station = LocalFrame(here["lat"], here["lon"]).to_latlon(0.0, -4.0)
    page.fill("#opt-radius", "3")
    page.click('[data-tool="station"]')
    page.mouse.click(*console.screen_point(page, *station))
    held = wait_until(
        lambda: console.newest_command(world, "demo-usv-1", "keep_station"), "station"
    )
    assert distance_m(held["args"]["lat"], held["args"]["lon"], *station) < 0.5
    assert held["args"]["radius_m"] == 3
    expect(console.command_item(page, held["command_id"])).to_have_attribute(
        "data-stage", "executing", timeout=30_000
    )
    expect(page.locator("path.leaflet-interactive[stroke-dasharray='3 4']")).to_have_count(1)
    shots(page, "station-here")

    # two selected (the fleet table's boxes): one Hold here reaches both
    page.click('[data-tab="fleet"]')
    page.locator('#fleet-table tr[data-vehicle="demo-usv-2"] input[type=checkbox]').check()
    expect(page.locator("#selection")).to_have_text("2 selected: H2OmniX Alpha, H2OmniX Bravo")
    expect(console.marker(page, "demo-usv-2")).to_have_class(re.compile(r"\bselected\b"))
    before = held["command_id"]
    # a radius or a speed out of its field's range is said, and nothing is sent (a
    # radius of 0 went out as 5 m)
    with no_requests(guard):
        page.fill("#opt-radius", "0")
        page.click("#hold")
        expect(page.locator("#toasts")).to_contain_text("station radius is 1 to 500 m")
        page.fill("#opt-speed", "25")
        page.click('[data-tool="go_to"]')
        # open water 20 m west of the boat (a click on its marker or label selects it)
        console.click_map(page, *LocalFrame(*station).to_latlon(-20.0, -5.0))
        expect(page.locator("#toasts")).to_contain_text("speed is 0.1 to 20 m/s")
        page.keyboard.press("Escape")  # the tool put away
        expect(page.locator("#tool-hint")).to_be_hidden()
        page.fill("#opt-speed", "")
        console.next_frames(page)
    page.fill("#opt-radius", "3")
    page.click("#hold")
    for vehicle_id in ("demo-usv-1", "demo-usv-2"):

        def hold(v: str = vehicle_id) -> dict[str, Any] | None:
            c = console.newest_command(world, v, "keep_station")
            return c if c and c["command_id"] != before and "lat" not in c["args"] else None

        assert wait_until(hold, f"Hold here for {vehicle_id}")["args"] == {"radius_m": 3}
    shots(page, "hold-two")


def test_draw_a_path_planned_round_an_obstacle(
    world: World, open_console: Any, shots: Shots
) -> None:
    here = console.position(world, "demo-usv-2")
    frame = LocalFrame(here["lat"], here["lon"])
    corners = [frame.to_latlon(e, n) for e, n in ((-6, 14), (6, 14), (6, 24), (-6, 24), (-6, 14))]
    world.fleet.call(
        "POST", "/api/obstacles",
        json={"name": "pontoon", "clearance_m": 3,
              "polygon": {"type": "Polygon", "coordinates": [[[o, a] for a, o in corners]]}},
    )  # fmt: skip
    corners = ((-10, -90), (10, -90), (10, -70), (-10, -70), (-10, -90))  # 80 m south
    shoal = [[o, a] for a, o in (frame.to_latlon(e, n) for e, n in corners)]
    polygon = {"type": "Polygon", "coordinates": [shoal]}
    body = {"name": "shoal", "kind": "no_go", "polygon": polygon}
    world.fleet.call("POST", "/api/zones", json=body)
    page, _ = open_console()
    console.log_in(page, "ana")
    expect(page.locator("path.obstacle")).to_have_count(1)
    expect(page.locator("path.zone-no_go")).to_have_count(1)
    console.centre_on(page, *frame.to_latlon(0, 20), 19)
    console.marker(page, "demo-usv-2").click()
    page.click('[data-tool="path"]')
    expect(page.locator("#path-bar")).to_be_visible()
    waypoints = [frame.to_latlon(0, 38), frame.to_latlon(10, 42)]
    for lat, lon in waypoints:
        page.mouse.click(*console.screen_point(page, lat, lon))
    expect(page.locator("#path-count")).to_have_text("2 waypoints")
    expect(page.locator(".waypoint")).to_have_count(2)
    assert page.locator("#path-plan").is_checked()
    shots(page, "path-drawn")
    page.click("#path-send")

    sent = wait_until(
        lambda: console.newest_command(world, "demo-usv-2", "follow_path"), "the path"
    )
    clicked = sent["args"]["waypoints"]
    for got, want in zip(clicked, waypoints, strict=True):
        assert distance_m(got["lat"], got["lon"], *want) < 0.5
    planned = sent["args"]["path"]  # the server planned it: round the pontoon
    assert len(planned) > len(clicked)
    item = console.command_item(page, sent["command_id"])
    expect(item).to_be_visible()
    expect(item).to_have_attribute("data-stage", "executing", timeout=30_000)
    expect(page.locator("path.planned.path-of-demo-usv-2")).to_be_visible()
    shots(page, "path-executing")

    if os.environ.get("FLEET_README_SHOT") == "1":
        page.evaluate("fleetConsole.map.fitFleet()")
        for close in page.locator("#toasts .close").all():
            close.click()
        console.next_frames(page)
        README_SHOT.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(README_SHOT))
    shots(page, "dashboard")


def test_a_straight_way_into_a_known_obstacle_is_asked_first(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A go_to straight across a moored barge went out at once; the server's note that its
    way runs into the barge came after, and the boat drove through it. The console asks
    first: Cancel sends nothing, "Send it anyway" sends it."""
    here = console.position(world, "demo-usv-3")
    frame = LocalFrame(here["lat"], here["lon"])
    corners = [frame.to_latlon(e, n) for e, n in ((-15, 25), (15, 25), (15, 35), (-15, 35))]
    body = {
        "name": "Moored barge",
        "polygon": console.polygon(corners),
    }
    barge = world.fleet.call("POST", "/api/obstacles", json=body)["obstacle_id"]
    try:
        page, guard = open_console()
        console.log_in(page, "ana")
        expect(page.locator("path.obstacle")).to_have_count(2)  # the pontoon and the barge
        console.centre_on(page, *frame.to_latlon(0, 30), 18)
        console.marker(page, "demo-usv-3").click()
        beyond = frame.to_latlon(0, 60)  # north, past the barge
        dialog = page.locator("#confirm")
        with no_requests(guard):
            page.click('[data-tool="go_to"]')
            console.click_map(page, *beyond)
            expect(dialog).to_be_visible()
            expect(page.locator("#confirm-title")).to_have_text(
                "H2OmniX Charlie's way runs into Moored barge"
            )
            shots(page, "asked-first")
            page.click("#confirm-cancel")
            expect(dialog).to_be_hidden()
        assert console.newest_command(world, "demo-usv-3", "go_to") is None
        clear = frame.to_latlon(-40, 0)  # west: clear of it, sent at once
        page.click('[data-tool="go_to"]')
        console.click_map(page, *clear)
        sent = wait_until(lambda: console.newest_command(world, "demo-usv-3", "go_to"), "go_to")
        assert distance_m(sent["args"]["lat"], sent["args"]["lon"], *clear) < 0.5
        expect(dialog).to_be_hidden()
        page.click('[data-tool="go_to"]')
        console.click_map(page, *beyond)
        page.locator("#confirm-ok").click()  # sent anyway, as the person decided
        wait_until(
            lambda: (
                (c := console.newest_command(world, "demo-usv-3", "go_to"))
                and c["command_id"] != sent["command_id"]
            ),
            "the go_to sent anyway",
        )
    finally:
        world.fleet.call("DELETE", f"/api/obstacles/{barge}")


def test_stop_needs_its_confirmation(world: World, open_console: Any, shots: Shots) -> None:
    page, guard = open_console()
    console.log_in(page, "ana")
    before = {c["command_id"] for c in world.fleet.call(
        "GET", "/client/get_fbmessage", params={"instance_id": world.instances["demo-usv-3"]}
    )["commands"]}  # fmt: skip
    console.marker(page, "demo-usv-3").click()
    page.click("#stop-selected")
    dialog = page.locator("#confirm")
    expect(dialog).to_be_visible()
    ok = page.locator("#confirm-ok")
    expect(ok).to_be_disabled()  # a second tap on Stop lands on nothing
    expect(page.locator("#confirm-cancel")).to_be_focused()  # Enter cancels
    shots(page, "stop-confirm")
    page.keyboard.press("Enter")
    expect(dialog).to_be_hidden()
    page.click("#stop-selected")
    expect(ok).to_be_enabled()
    page.keyboard.press("Escape")
    expect(dialog).to_be_hidden()
    console.next_frames(page)
    assert not [r for r in guard.requests if "/client/submit_control" in r], "sent unconfirmed"
    after = world.fleet.call(
        "GET", "/client/get_fbmessage", params={"instance_id": world.instances["demo-usv-3"]}
    )["commands"]
    assert [c for c in after if c["command_id"] not in before] == [], "sent without confirming"

    page.click('#actions button[data-tool="go_to"]')  # a tool armed when Stop is pressed
    page.click("#stop-selected")
    expect(ok).to_be_enabled()
    ok.click()
    # the stop disarms it: a look at the map afterwards does not send the vehicle off again
    expect(page.locator("#actions button[data-tool].active")).to_have_count(0)
    expect(page.locator("#tool-hint")).to_be_hidden()
    stop = wait_until(
        lambda: console.newest_command(world, "demo-usv-3", "stop"), "the stop stored"
    )
    assert stop["command_id"] not in before
    item = console.command_item(page, stop["command_id"])
    expect(item).to_have_attribute("data-stage", "done", timeout=30_000)
    shots(page, "stopped")

    # Stop all: its own confirmation, then a stop for every vehicle
    page.click("#stop-all")
    expect(page.locator("#confirm-title")).to_have_text("Stop every vehicle?")
    # the vehicles counted as vehicles, not "running" (read as under way: some are idle)
    expect(page.locator("#confirm-text")).to_contain_text("Every vehicle you can see (3 vehicles")
    expect(ok).to_be_disabled()
    shots(page, "stop-all-confirm")
    expect(ok).to_be_enabled()
    ok.click()
    for vehicle_id in console.ALL:

        def new_stop(v: str = vehicle_id) -> dict[str, Any] | None:
            c = console.newest_command(world, v, "stop")
            return c if c and c["command_id"] != stop["command_id"] else None

        stopped = wait_until(new_stop, f"a stop for {vehicle_id}")
        assert stopped["issued_by"] == "ana"
        expect(console.marker(page, vehicle_id).locator(".chip")).to_contain_text("stop ·")
    shots(page, "stopped-all")
