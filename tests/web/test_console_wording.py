"""What the console says and offers, in a real browser (as test_console_commands): a pasted
token that ends asks for the new one, what is said is said once, an empty replay window
says so, a viewer is offered no command (and an operator's stop waits an hour for a
vehicle out of reach), a vehicle gone offline shows its stage as last known, and a
phone's header says who is logged in. A world of its own (the module's), in file order:
ana holds every vehicle at the start; the last two stop an agent, then the server."""

from __future__ import annotations

import re
from typing import Any

import pytest
from playwright.sync_api import expect

from server.demo import VEHICLES
from tests.agent.procs import wait_until
from tests.web import console_helpers as console
from tests.web.conftest import PASSWORD, Shots, World
from vehicle_client.geo import LocalFrame

pytestmark = [pytest.mark.slow, pytest.mark.browser]


def test_a_pasted_token_that_ends_asks_for_the_new_one(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A demo server prints a new admin token at every start: an admin who had pasted the
    old one was told to sign in again, with the token's section closed."""
    ids = [v[0] for v in VEHICLES]
    body = {"username": "eve", "role": "operator", "vehicles": ids}
    old = world.fleet.call("POST", "/api/users", json=body)["token"]
    page, _ = open_console()
    page.goto("/")
    page.click("#login details summary")
    page.fill("#login-token", old)
    page.click("#login-token-go")
    expect(page.locator("#link")).to_have_attribute("data-state", "live")
    new = world.fleet.call("POST", "/api/users/eve/rotate_token")["token"]  # the old one ends
    page.evaluate("fleetConsole.live.reconnectNow()")  # as after a restart: refused (4401)
    expect(page.locator("#login-error")).to_have_text(
        "the token you pasted is no longer accepted (revoked, or a new one was made, as a demo "
        "server does each time it starts): paste the new token the server printed",
        timeout=15_000,
    )
    expect(page.locator("#login details")).to_have_attribute("open", "")
    expect(page.locator("#login-token")).to_be_focused()
    shots(page, "paste-the-new-one")
    page.keyboard.type(new)
    page.click("#login-token-go")
    expect(page.locator("#link")).to_have_attribute("data-state", "live")
    expect(page.locator("#who")).to_have_text("eve · operator")


def test_what_is_said_is_said_once_and_an_empty_window_says_so(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A path refused to two boats read "...; nothing queued: <the same reason>"; two sent
    to one point are told they meet there (the server's warning); a release
    read "control released by ana (by ana)"; the replay of a window with nothing in it
    said "0 stored positions, 0 events"."""
    for vehicle in ("demo-usv-1", "demo-usv-2"):
        world.fleet.grant(world.instances[vehicle], "ana")
    here = console.position(world, "demo-usv-1")
    frame = LocalFrame(here["lat"], here["lon"])
    corners = [frame.to_latlon(e, n) for e, n in ((-15, 45), (15, 45), (15, 75), (-15, 75))]
    ring = [[o, a] for a, o in [*corners, corners[0]]]
    body = {"name": "reef", "kind": "no_go", "polygon": {"type": "Polygon", "coordinates": [ring]}}
    world.fleet.call("POST", "/api/zones", json=body)
    page, _ = open_console()
    console.log_in(page, "ana")
    expect(page.locator("path.zone-no_go")).to_have_count(1)
    console.centre_on(page, *frame.to_latlon(0, 0), 17)
    console.marker(page, "demo-usv-1").click()
    console.marker(page, "demo-usv-2").click(modifiers=["Shift"])
    expect(page.locator("#selection")).to_have_text("2 selected: H2OmniX Alpha, H2OmniX Bravo")
    page.click('#actions [data-tool="path"]')
    # one path for two boats is not planned (the planner keeps boats apart): said, and off
    expect(page.locator("#path-plan")).to_be_disabled()
    page.mouse.click(*console.screen_point(page, *frame.to_latlon(0, 60)))  # in the reef
    page.click("#path-send")
    refused = page.locator("#toasts .toast.error", has_text="follow path NOT sent")
    expect(refused).to_contain_text(  # each boat by name, the reason once each
        re.compile(r"to any of them: H2OmniX Alpha: [^;]*reef[^;]*; H2OmniX Bravo: [^;]*reef")
    )
    shots(page, "refused-once")
    page.keyboard.press("Escape")
    page.click('#actions [data-tool="go_to"]')  # both to one point: queued, and said
    page.mouse.click(*console.screen_point(page, *frame.to_latlon(-40, -20)))  # clear of the boats
    warned = page.locator("#toasts .toast.warn")
    expect(warned).to_contain_text("note: 2 vehicles sent to one point")
    shots(page, "meeting-warned")
    world.as_user(
        "ana",
        "POST",
        "/client/release_control",
        json={"instance_id": world.instances["demo-usv-1"]},
    )
    page.click('[data-tab="control"]')
    line = page.locator('section.safety-log li[data-kind="control_release"]').first
    expect(line).to_contain_text("control released by ana")
    expect(line).not_to_contain_text("(by ana)")
    page.click('[data-tab="replay"]')
    start, end = console.local_times(page, 3, 2)  # ended an hour before this server started
    page.locator("#replay-from").fill(start)
    page.locator("#replay-to").fill(end)
    page.click("#replay-load")
    expect(page.locator("#replay-info")).to_contain_text(
        re.compile(r"^Nothing was recorded for these vehicles from .+ to .+: no position, no event")
    )
    expect(page.locator("#replay-info")).to_contain_text("Try a wider window")
    expect(page.locator("#replay-bar")).to_be_hidden()  # the map stays live
    shots(page, "empty-window")


def test_a_viewer_is_offered_no_command_and_a_stop_waits_an_hour(
    world: World, open_console: Any
) -> None:
    """A viewer reads: no Stop all, no tools over the map (each was offered, then refused).
    An operator's stop waits for a vehicle out of reach the longest a command may: one
    that expired after 30 s (the contract's default) never reached a boat back later."""
    ids = [v[0] for v in VEHICLES]
    body = {"username": "vic", "role": "viewer", "vehicles": ids, "password": PASSWORD}
    world.fleet.call("POST", "/api/users", json=body)
    page, _ = open_console()
    console.log_in(page, "vic")
    expect(page.locator("#stop-all")).to_be_hidden()
    console.marker(page, "demo-usv-1").click()
    expect(page.locator("#selection")).to_be_hidden()
    expect(page.locator("#actions")).to_be_hidden()
    page, _ = open_console()
    console.log_in(page, "ben")
    console.marker(page, "demo-usv-1").click()
    page.click("#stop-selected")
    ok = page.locator("#confirm-ok")
    expect(ok).to_be_enabled()
    ok.click()
    stop = wait_until(lambda: console.newest_command(world, "demo-usv-1", "stop"), "the stop")
    lasts = console.ms(stop["expires_at"]) - console.ms(stop["issued_at"])
    assert lasts == 3_600_000, lasts


def test_a_vehicle_gone_offline_shows_its_stage_as_last_known(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A boat offline for 45 s still read "follow_path · executing" in orange on the map and
    in the table, its battery as live as the others'. (Last: its agent stays stopped.)"""
    vehicle, instance = "demo-usv-2", world.instances["demo-usv-2"]
    world.fleet.grant(instance, "ana")
    here = console.position(world, vehicle)
    far = LocalFrame(here["lat"], here["lon"]).to_latlon(0.0, 2000.0)
    world.fleet.submit(world.tokens["ana"], instance, "go_to", {"lat": far[0], "lon": far[1]})
    page, _ = open_console()
    console.log_in(page, "mia")
    label = console.marker(page, vehicle).locator(".chip")
    expect(label).to_have_text("go to · executing", timeout=30_000)
    row = page.locator(f'#fleet-table tr[data-vehicle="{vehicle}"]')
    console.marker(page, vehicle).click()
    page.click('[data-tab="fleet"]')
    world.agents[[v[0] for v in VEHICLES].index(vehicle)].stop()  # out of reach
    expect(console.marker(page, vehicle)).to_have_attribute(
        "data-presence", "offline", timeout=30_000
    )
    expect(label).to_have_text("go to · executing (last known)")
    expect(label).to_have_class(re.compile(r"\blast-known\b"))
    expect(row.locator(".chip")).to_have_text("go to · executing (last known)")
    expect(row.locator("td").nth(3)).to_have_class(re.compile(r"\bstale\b"))  # its battery
    shots(page, "offline-table")
    page.click('[data-tab="vehicle"]')
    item = page.locator("#vehicle-pane li[data-command]").first
    expect(item).to_have_class(re.compile(r"\blast-known\b"))
    expect(item.locator(".steps")).to_contain_text("executing (last known)")
    shots(page, "offline-panel")
    page.click('[data-tab="control"]')  # the manager's log says it went offline
    gone = page.locator('section.safety-log li[data-kind="presence"]').first
    expect(gone).to_contain_text("H2OmniX Bravo is now offline")


def test_a_phone_says_who_is_logged_in_and_what_a_finger_does(
    world: World, open_console: Any, shots: Shots
) -> None:
    """On a 390 px phone the header hid who was logged in and took two rows while the link
    was lost, toasts covered the panels' headings, and the hints spoke of ctrl-click and
    Esc. (Last: the server is stopped and started again.)"""
    page, _ = open_console(viewport=(390, 844), is_mobile=True, has_touch=True)
    console.log_in(page, "mia")
    bar, who = page.locator("header.bar"), page.locator("#who")
    expect(who).to_be_visible()
    expect(who).to_have_text("mia · manager")
    one_row = console.box_of(bar)["height"]
    assert one_row < 56, one_row
    console.marker(page, "demo-usv-1").tap()
    page.locator('#actions [data-tool="go_to"]').tap()
    hint = page.locator("#tool-hint")
    expect(hint).to_have_text(
        "Tap the map where the selected vehicles should go (tap Go to again: cancel)."
    )
    page.locator('#actions [data-tool="go_to"]').tap()
    expect(hint).to_be_hidden()
    page.locator('[data-tab="fleet"]').tap()
    fleet_hint = page.locator('[data-pane="fleet"] p.hint')
    expect(fleet_hint.locator(".touch-only")).to_be_visible()
    expect(fleet_hint.locator(".touch-only")).to_have_text(
        "Tap a vehicle on the map or here; tick the boxes to select several."
    )
    expect(fleet_hint.locator(".mouse-only")).to_be_hidden()  # ctrl- or shift-click
    page.locator('[data-tab="control"]').tap()
    instance = world.instances["demo-usv-1"]
    world.as_user("ana", "POST", "/client/request_control", json={"instance_id": instance})
    toast = page.locator("#toasts .toast", has_text="ana asks for control")
    expect(toast).to_be_visible()
    for heading in page.locator("#control-pane h2, #control-pane .requests h3").all():
        assert not console.boxes_overlap(console.box_of(toast), console.box_of(heading)), (
            heading.inner_text()
        )
    shots(page, "toast-clear-of-headings")
    world.server.stop(grace_s=5.0)
    expect(page.locator("#link")).to_have_attribute("data-state", "lost")
    expect(page.locator("#link")).to_contain_text("link lost")
    assert console.box_of(bar)["height"] == one_row, page.locator("#link").inner_text()
    assert page.evaluate("document.documentElement.scrollWidth") <= 390
    shots(page, "link-lost")
    world.server.start()
    expect(page.locator("#link")).to_have_attribute("data-state", "live", timeout=30_000)
    assert console.box_of(bar)["height"] == one_row
