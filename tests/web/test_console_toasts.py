"""Toasts on a phone, in a real browser (as test_console_commands): a burst of them
(requests for control, stops, alarms in a row) stacked down over the map and the action
bar, so the field manager could not reach Stop. At most three show now, the rest behind a
"+N more" that opens the log of every message. Over a pane they covered the last lease
card's Revoke: the pane ends above them now. A world of its own (the module's)."""

from __future__ import annotations

from typing import Any

import pytest
from playwright.sync_api import expect

from tests.web.conftest import PASSWORD, Shots, World
from tests.web.console_helpers import ALL, log_in, marker, next_frames

pytestmark = [pytest.mark.slow, pytest.mark.browser]

#: Buttons (of the action bar, by default) whose centre is not the button itself (or
#: inside it): covered.
COVERED = """(sel = "#actions .actions-row button") => [...document.querySelectorAll(sel)]
    .filter((b) => b.offsetParent !== null)
    .filter((b) => {
        const r = b.getBoundingClientRect();
        const hit = document.elementFromPoint(r.left + r.width / 2, r.top + r.height / 2);
        return !(hit && b.contains(hit));
    })
    .map((b) => b.textContent.trim())"""

#: The buttons of a panel that show in its scrolling area (a person sees them) but whose
#: centre is something else (a toast), and how many toasts show meanwhile.
COVERED_IN_VIEW = """(sel) => {
    const area = document.querySelector(".side").getBoundingClientRect();
    const covered = [...document.querySelectorAll(sel)]
        .filter((b) => b.checkVisibility()) // (a closed <details>' are laid out, not shown)
        .filter((b) => {
            const r = b.getBoundingClientRect();
            const x = r.left + r.width / 2;
            const y = r.top + r.height / 2;
            if (y < area.top || y > area.bottom || y > innerHeight) return false; // scrolled away
            const hit = document.elementFromPoint(x, y);
            return !(hit && b.contains(hit));
        })
        .map((b) => b.textContent.trim());
    const toasts = [...document.querySelectorAll("#toasts .toast")]
        .filter((t) => t.offsetParent !== null).length;
    return { covered, toasts };
}"""


def test_a_burst_of_toasts_on_a_phone_leaves_the_action_bar_clear(
    world: World, open_console: Any, shots: Shots
) -> None:
    page, _ = open_console(viewport=(390, 844), is_mobile=True, has_touch=True)
    log_in(page, "mia")
    marker(page, "demo-usv-1").tap()
    expect(page.locator("#actions")).to_be_visible()
    assert page.evaluate(COVERED) == []
    askers = ["ben", "cy", "dee", "eli"]
    for username in askers[1:]:
        body = {
            "username": username,
            "role": "operator",
            "vehicles": list(ALL),
            "password": PASSWORD,
        }
        world.tokens[username] = world.fleet.call("POST", "/api/users", json=body)["token"]
    # twelve requests in a row: twelve toasts for the manager within a second or two
    for username in askers:
        for vehicle in ALL:
            body = {"instance_id": world.instances[vehicle]}
            world.as_user(username, "POST", "/client/request_control", json=body)
    toasts = page.locator("#toasts .toast")
    expect(toasts).to_have_count(12)
    covered = page.evaluate(COVERED)
    shots(page, "twelve-toasts")
    assert covered == [], f"toasts cover the action bar: {covered}"
    # nor the map's own buttons: the zoom, and All boats under it
    on_map = page.evaluate(COVERED, ".leaflet-control-zoom a, .fit-all")
    assert on_map == [], f"toasts cover the map's buttons: {on_map}"
    expect(page.locator("#toasts .toast:visible")).to_have_count(3)  # the newest three
    expect(toasts.last).to_contain_text("eli asks for control of H2OmniX Charlie")
    more = page.locator("#toasts .toast-more")
    expect(more).to_have_text("+9 more")
    # the buttons answer a finger: Go to arms (and disarms), Stop asks
    go_to = page.locator('#actions [data-tool="go_to"]')
    go_to.tap()
    expect(page.locator("#tool-hint")).to_be_visible()
    go_to.tap()
    expect(page.locator("#tool-hint")).to_be_hidden()
    page.locator("#stop-selected").tap()
    expect(page.locator("#confirm-title")).to_have_text("Stop H2OmniX Alpha?")
    page.locator("#confirm-cancel").tap()
    expect(page.locator("#confirm")).to_be_hidden()
    # "+9 more" opens the log: every message, the newest first
    more.tap()
    log = page.locator("#toast-log-list li")
    expect(page.locator("#toast-log")).to_be_visible()
    expect(log.filter(has_text="asks for control")).to_have_count(12)
    expect(log.first).to_contain_text("eli asks for control of H2OmniX Charlie")
    shots(page, "toast-log")
    page.locator("#toast-log-close").tap()
    expect(page.locator("#toast-log")).to_be_hidden()
    # they still go on their own, and so does the count
    expect(toasts).to_have_count(0, timeout=15_000)
    expect(more).to_have_count(0)


def test_toasts_on_a_phone_s_panel_leave_its_buttons_clear(
    world: World, open_console: Any, shots: Shots
) -> None:
    """On a phone's Control tab a toast at the bottom covered the last lease card's Revoke
    for a few seconds, just as the field manager scrolled down to it. The panel now ends
    above the toasts while they show: scrolled to its end, every button is clear of them."""
    page, _ = open_console(viewport=(390, 844), is_mobile=True, has_touch=True)
    log_in(page, "mia")
    page.locator('.tabs [data-tab="control"]').tap()
    leases = page.locator("#control-pane li.lease")
    expect(leases).to_have_count(3)
    body = {"username": "gus", "role": "operator", "vehicles": list(ALL), "password": PASSWORD}
    world.tokens["gus"] = world.fleet.call("POST", "/api/users", json=body)["token"]
    for vehicle in ALL:  # three toasts for the manager
        body = {"instance_id": world.instances[vehicle]}
        world.as_user("gus", "POST", "/client/request_control", json=body)
    expect(page.locator("#toasts .toast:visible")).to_have_count(3)
    next_frames(page)
    revoke = leases.last.locator("button", has_text="Revoke")
    # scrolled down until the last card's Revoke shows, at the panel's bottom
    revoke.evaluate("el => el.scrollIntoView({block: 'end'})")
    next_frames(page)
    shown = page.evaluate(COVERED_IN_VIEW, "#control-pane button")
    shots(page, "control-tab-with-toasts")
    assert shown["toasts"] == 3, shown  # still up while it was measured
    assert shown["covered"] == [], f"toasts cover the panel's buttons: {shown}"
    revoke.tap()
    expect(page.locator("#confirm-title")).to_contain_text("Revoke ana's control of")
    page.locator("#confirm-cancel").tap()
    expect(page.locator("#confirm")).to_be_hidden()
