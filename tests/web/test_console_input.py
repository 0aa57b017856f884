"""What is typed and clicked in the console does what the person meant, in a real browser
(as test_console_commands): a number field reads a decimal comma as a point and refuses
anything else, a double click does not act twice nor on a button that appeared under the
pointer (and Release asks first) nor on the map under a confirmation, and arming a tool
moves no button. A world of its own
(the module's), in file order: ana holds every vehicle at the start."""

from __future__ import annotations

import re
from typing import Any

import pytest
from playwright.sync_api import expect

from tests.agent.procs import wait_until
from tests.web import console_helpers as console
from tests.web.conftest import Shots, World, no_requests
from vehicle_client.geo import LocalFrame, distance_m

pytestmark = [pytest.mark.slow, pytest.mark.browser]


def test_a_decimal_comma_is_a_point_and_anything_else_is_refused(
    world: World, open_console: Any, shots: Shots
) -> None:
    """Chromium in English dropped the comma of "0,3" in a number field: the go_to went at
    3 m/s. "1e400" became an empty field, sent as the vehicle's own speed."""
    page, guard = open_console()
    console.log_in(page, "ana")
    vehicle = "demo-usv-2"
    start = console.position(world, vehicle)
    console.centre_on(page, start["lat"], start["lon"], 19)
    console.marker(page, vehicle).click()
    target = LocalFrame(start["lat"], start["lon"]).to_latlon(4.0, 6.0)
    speed, radius = page.locator("#opt-speed"), page.locator("#opt-radius")
    toasts = page.locator("#toasts")
    page.click('[data-tool="go_to"]')
    with no_requests(guard):
        for typed in ("1e400", "0x3", "1,5.2", "2 m/s", "Infinity"):
            speed.fill("")
            speed.press_sequentially(typed)  # as a person types it
            page.mouse.click(*console.screen_point(page, *target))
            expect(toasts).to_contain_text(f'"{typed}" is not a plain number')
        expect(page.locator("#tool-hint")).to_be_visible()  # the tool waits for a good one
        speed.fill("")
        speed.press_sequentially("25")
        page.mouse.click(*console.screen_point(page, *target))
        expect(toasts).to_contain_text("speed is 0.1 to 20 m/s, or empty for the vehicle's own")
        radius.fill("")
        radius.press_sequentially("-5")
        page.click("#hold")
        expect(toasts).to_contain_text("station radius is 1 to 500 m (not -5)")
    shots(page, "refused")
    speed.fill("")
    speed.press_sequentially("0,3")
    page.mouse.click(*console.screen_point(page, *target))
    sent = wait_until(lambda: console.newest_command(world, vehicle, "go_to"), "the go_to")
    assert sent["args"]["speed_mps"] == 0.3, sent["args"]
    assert distance_m(sent["args"]["lat"], sent["args"]["lon"], *target) < 0.5
    radius.fill("")
    radius.press_sequentially("2,5")
    page.click("#hold")

    def hold() -> dict[str, Any] | None:
        c = console.newest_command(world, vehicle, "keep_station")
        return c if c and "lat" not in c["args"] else None

    assert wait_until(hold, "Hold here")["args"] == {"radius_m": 2.5}
    shots(page, "sent")
    # a click that lands 20 km away (a zoomed-out map) asks first; cancelled: nothing sent
    far = LocalFrame(start["lat"], start["lon"]).to_latlon(20_000.0, 0.0)
    console.centre_on(page, far[0], far[1], 15)
    page.click('[data-tool="go_to"]')
    with no_requests(guard):
        page.mouse.click(*console.screen_point(page, *far))
        expect(page.locator("#confirm-title")).to_have_text(
            re.compile(r"^Send H2OmniX Bravo 20 km away\?$")
        )
        page.locator("#confirm-cancel").click()
        expect(page.locator("#confirm")).not_to_be_visible()


def test_a_double_click_on_a_fleet_row_does_not_release_control(
    world: World, open_console: Any, shots: Shots
) -> None:
    """The row's first click opened the Vehicle tab, whose Release button came up under the
    pointer, and the second click released control. Now the rest of that double click is
    dropped, and Release asks first anyway (as Revoke)."""
    page, guard = open_console()
    console.log_in(page, "ana")
    release = page.locator("#vehicle-pane button", has_text="Release")
    console.marker(page, "demo-usv-3").click()  # where its Vehicle tab has Release
    box = console.box_of(release)
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.click('[data-tab="fleet"]')
    vehicle = page.evaluate(
        "([x, y]) => document.elementFromPoint(x, y).closest('tr[data-vehicle]').dataset.vehicle",
        [x, y],
    )  # the fleet row at that point (a vehicle ana holds, as every one)
    instance = world.instances[vehicle]
    page.mouse.click(x, y)  # the double click's first click: the row's Vehicle tab opens
    expect(page.locator('.tabs [data-tab="vehicle"]')).to_have_attribute("aria-selected", "true")
    now = console.box_of(release)
    assert now["x"] < x < now["x"] + now["width"] and now["y"] < y < now["y"] + now["height"]
    page.mouse.down(click_count=2)  # its second, on the Release now under the pointer
    page.mouse.up(click_count=2)
    console.next_frames(page)
    expect(page.locator("#confirm")).to_be_hidden()
    assert not [r for r in guard.requests if "/client/release_control" in r]
    shots(page, "after-double-click")
    release.click()  # meant: it asks first
    expect(page.locator("#confirm-title")).to_have_text(
        re.compile(r"^Release your control of H2OmniX \w+\?$")
    )
    page.locator("#confirm-cancel").click()
    expect(page.locator("#confirm")).to_be_hidden()
    assert not [r for r in guard.requests if "/client/release_control" in r]
    assert console.lease_of(world, instance)["holder"] == "ana"
    release.click()
    ok = page.locator("#confirm-ok")
    expect(ok).to_be_enabled()
    ok.click()
    expect(page.locator("#vehicle-pane .control-line")).to_contain_text("nobody holds control")
    assert console.lease_of(world, instance) is None
    world.fleet.grant(instance, "ana")  # as it was, for the tests that follow


def test_a_double_click_sends_once(world: World, open_console: Any, shots: Shots) -> None:
    """A double click on Request control asked twice, and one on a request card's Grant
    granted twice: a button that sends a call is disabled while the call is in flight."""
    vehicle, instance = "demo-usv-3", world.instances["demo-usv-3"]
    world.fleet.call("POST", "/client/revoke_control", json={"instance_id": instance})
    operator, asked = open_console()
    console.log_in(operator, "ben")
    console.marker(operator, vehicle).click()
    panel = operator.locator("#vehicle-pane")
    panel.locator("button", has_text="Request control").dblclick()
    expect(panel.locator("button", has_text="Requested…")).to_be_disabled()
    assert calls(asked, "/client/request_control") == 1
    manager, granted = open_console()
    console.log_in(manager, "mia")
    manager.click('[data-tab="control"]')
    card = manager.locator(f'form.request[data-user="ben"][data-vehicle="{vehicle}"]')
    card.locator("button[type=submit]").dblclick()
    expect(card).to_have_count(0)
    expect(manager.locator(f'li.lease[data-vehicle="{vehicle}"]')).to_contain_text("ben until")
    assert calls(granted, "/client/grant_control") == 1
    shots(manager, "granted-once")


def test_arming_a_tool_moves_no_button(world: World, open_console: Any, shots: Shots) -> None:
    """Arming Path grew the action bar upward over its own buttons: a click meant for the
    map then landed on Hold here, which sends at once. The rows a tool adds go above."""
    page, _ = open_console()
    console.log_in(page, "ana")
    console.marker(page, "demo-usv-1").click()
    buttons = ["#hold", "#stop-selected", '#actions [data-tool="path"]']
    before = [console.box_of(page.locator(b)) for b in buttons]
    page.click('#actions [data-tool="path"]')
    expect(page.locator("#path-bar")).to_be_visible()
    assert [console.box_of(page.locator(b)) for b in buttons] == before
    page.click("#path-cancel")
    page.click('#actions [data-tool="go_to"]')
    expect(page.locator("#tool-hint")).to_be_visible()
    assert [console.box_of(page.locator(b)) for b in buttons] == before
    shots(page, "armed-nothing-moved")
    page.keyboard.press("Escape")


def calls(guard: Any, path: str) -> int:
    """How many times the page called ``path``."""
    return len([r for r in guard.requests if r.startswith("POST ") and r.endswith(path)])


def test_a_double_click_on_a_confirmation_does_not_reach_the_map(
    world: World, open_console: Any, shots: Shots
) -> None:
    """Go to armed, Stop, then a double click on "Stop it": its second click reached the
    map under the dialog, and the armed Go to sent the boat there (before the stop); the
    map zoomed in too. The stop alone goes now, and the map stays as it was."""
    vehicle, instance = "demo-usv-1", world.instances["demo-usv-1"]
    world.fleet.grant(instance, "ana")
    page, sent = open_console()
    console.log_in(page, "ana")
    console.marker(page, vehicle).click()
    page.click('#actions [data-tool="go_to"]')
    expect(page.locator("#tool-hint")).to_be_visible()
    zoom = page.evaluate("fleetConsole.map.map.getZoom()")
    page.click("#stop-selected")
    ok = page.locator("#confirm-ok")
    expect(ok).to_be_enabled()  # armed after a moment
    box = console.box_of(ok)
    map_box = console.box_of(page.locator("#map"))
    assert map_box["x"] + map_box["width"] > box["x"] + box["width"] / 2  # over the map
    ok.dblclick()
    stop = wait_until(lambda: console.newest_command(world, vehicle, "stop"), "the stop")
    console.next_frames(page)
    assert calls(sent, "/client/submit_control") == 1  # the stop, and no go_to
    assert page.evaluate("fleetConsole.map.map.getZoom()") == zoom
    expect(page.locator("#tool-hint")).to_be_hidden()  # the stop put the tool away
    assert stop["issued_by"] == "ana"
    shots(page, "stopped-nothing-else")
