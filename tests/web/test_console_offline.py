"""A boat out of contact, as a field manager's and her operators' test of the console found
it, in a real browser (as test_console_told): a revoke told the operator that the boat held
station and the manager twice, in contradicting words, though the hold was only queued (it
later expired unheard); a replay showed nothing of a ticked boat with no positions in the
window; the parameters panel did not say how old the parameters of a boat offline were, nor
when a refresh read them; a stop for a boat out of contact was asked, and told to the
manager, as if it stopped at once. A world of its own (the module's), in file order:
Bravo's agent is stopped in the first test and stays stopped."""

from __future__ import annotations

import re
from typing import Any

import pytest
from playwright.sync_api import expect

from server.demo import VEHICLES
from tests.agent.procs import wait_until
from tests.web.conftest import Shots, World
from tests.web.console_helpers import ALL, local_times, log_in, marker, ms, position, replay_up

pytestmark = [pytest.mark.slow, pytest.mark.browser]

VEHICLE = "demo-usv-2"  # H2OmniX Bravo
QUEUED = "H2OmniX Bravo is offline: the hold is queued and reaches it only when it is back"
CLOCK = r"\d\d:\d\d:\d\d"


def toasts(page: Any) -> Any:
    return page.locator("#toasts .toast .msg")


def presence(world: World) -> str:
    return str(world.fleet.call("GET", f"/api/vehicles/{VEHICLE}")["presence"])


def test_a_revoke_of_a_boat_out_of_contact_says_once_that_the_hold_is_queued(
    world: World, open_console: Any, shots: Shots
) -> None:
    """ana held Bravo, offline; mia revoked. ana read "...revoked by mia; it holds station";
    mia read "...holds station: ... keeps station where it is" and "...is offline: the hold
    is queued ...". Each is told once now, and only that the hold is queued."""
    agent = world.agents[[v[0] for v in VEHICLES].index(VEHICLE)]
    manager, _ = open_console()
    log_in(manager, "mia")
    operator, _ = open_console()
    log_in(operator, "ana")  # she holds every boat (the world's grants)
    agent.stop()
    wait_until(lambda: presence(world) == "offline", "Bravo offline")
    expect(marker(manager, VEHICLE)).to_have_attribute("data-presence", "offline")
    expect(marker(operator, VEHICLE)).to_have_attribute("data-presence", "offline")
    # a boat gone out of contact is said, with no mission under way too (it went unsaid)
    gone = toasts(manager).filter(
        has_text=re.compile(r"^out of contact: H2OmniX Bravo \(last heard \d")
    )
    expect(gone).to_have_count(1)
    gone.locator("xpath=..").locator(".close").click()

    manager.click('[data-tab="control"]')
    manager.locator(f'li.lease[data-vehicle="{VEHICLE}"]').get_by_role(
        "button", name="Revoke"
    ).click()
    manager.locator("dialog[open]").get_by_role("button", name="Revoke").click()
    # the hold the server queued is in the manager's log: every toast of it has come
    log = manager.locator("section.safety-log")
    held = log.locator(f'li[data-kind="hold_station"][data-vehicle="{VEHICLE}"]')
    expect(held).to_have_count(1)
    about = toasts(manager).filter(has_text="H2OmniX Bravo")
    expect(about).to_have_count(1)
    expect(about).to_contain_text("control of H2OmniX Bravo revoked")
    expect(about).to_contain_text(QUEUED)
    shots(manager, "manager-told-once")
    # and the log says it without "keeps station" a second time
    expect(held).to_contain_text("H2OmniX Bravo told to hold station: ana's control ended")
    expect(held).not_to_contain_text("keeps station")

    told = toasts(operator).filter(has_text="your control of H2OmniX Bravo was revoked by mia")
    expect(told).to_have_count(1)
    expect(told).to_contain_text(QUEUED)
    expect(told).not_to_contain_text("it holds station")
    expect(toasts(operator).filter(has_text="holds station")).to_have_count(0)
    shots(operator, "operator-told-queued")


def test_a_replay_names_a_ticked_boat_with_no_positions_in_its_window(
    world: World, open_console: Any, shots: Shots
) -> None:
    """Three boats ticked, "3 vehicle(s), 600 stored positions", two on the map: Bravo,
    offline before the window began, was left out without a word."""
    assert presence(world) == "offline"
    page, _ = open_console()
    log_in(page, "mia")
    replay_up(page)
    page.click('[data-tab="replay"]')
    start, end = local_times(page, 0, -1 / 60)  # from now to a minute on
    page.locator("#replay-from").fill(start)
    page.locator("#replay-to").fill(end)
    for vehicle_id in ALL:
        page.locator(f'#replay-vehicles input[value="{vehicle_id}"]').check()
    since = ms(position(world, "demo-usv-1")["ts"])
    wait_until(  # the others' positions come into the window (2 a second)
        lambda: ms(position(world, "demo-usv-1")["ts"]) > since + 2000, "positions in it", 10
    )
    page.click("#replay-load")
    expect(page.locator("#replay-bar")).to_be_visible()
    missing = re.compile(rf"H2OmniX Bravo: no positions in this window \(offline since {CLOCK}\)")
    expect(page.locator("#replay-info")).to_contain_text(missing)
    expect(page.locator("#replay-info")).to_contain_text(re.compile(r"^3 vehicles, \d+ stored"))
    status = page.locator("#replay-status")  # said on the map too, whatever the cursor
    expect(status).to_be_visible()
    expect(status).to_contain_text(missing)
    expect(page.locator(".vicon.replay")).to_have_count(2)
    shots(page, "no-positions-said")
    page.locator("#replay-slider").fill("30000")
    expect(status).to_contain_text(missing)
    page.click("#replay-exit")


def test_the_parameters_of_a_boat_offline_say_how_old_they_are(
    world: World, open_console: Any, shots: Shots
) -> None:
    """Bravo's parameters showed as if live, and "refresh" gave no sign it had read them."""
    assert presence(world) == "offline"
    page, _ = open_console()
    log_in(page, "ana")
    marker(page, VEHICLE).click()
    params = page.locator("#vehicle-pane .params-note")
    dated = re.compile(rf"^as of {CLOCK}: the vehicle is offline; read at {CLOCK}$")
    expect(params).to_have_text(dated)
    read = params.inner_text()
    wait_until(  # a second on: the next reading has another time
        lambda: page.evaluate("new Date().toLocaleTimeString([], {hour12: false})") != read[-8:],
        "the page's clock to tick",
        5,
    )
    page.locator("#vehicle-pane button", has_text="refresh").click()
    expect(params).not_to_have_text(read)
    expect(params).to_have_text(re.compile(rf"read at {CLOCK}$"))
    shots(page, "params-dated")


def test_a_stop_for_a_boat_out_of_contact_says_it_is_queued(
    world: World, open_console: Any, shots: Shots
) -> None:
    """The question before a stop said "H2OmniX Bravo will stop at once" for a boat
    offline for minutes: it gets the stop only when it is back."""
    assert presence(world) == "offline"
    page, _ = open_console()
    log_in(page, "ana")
    marker(page, VEHICLE).click()
    marker(page, "demo-usv-1").click(modifiers=["Shift"])  # and Alpha, online
    page.click("#stop-selected")
    text = page.locator("#confirm-text")
    expect(text).to_contain_text("H2OmniX Alpha will stop at once")
    expect(text).to_contain_text(
        "H2OmniX Bravo is out of contact: the stop is queued and reaches it only when back"
    )
    expect(text).not_to_contain_text("Bravo will stop at once")
    shots(page, "stop-offline-asked")
    page.locator("#confirm-cancel").click()
    expect(page.locator("#confirm")).to_be_hidden()
    # the manager is told that it was sent, not that the boat stopped
    manager, _ = open_console()
    log_in(manager, "mia")
    world.fleet.submit(world.tokens["ana"], world.instances[VEHICLE], "stop", {})
    told = toasts(manager).filter(has_text="ana sent a stop to H2OmniX Bravo, out of contact")
    expect(told).to_have_count(1)
    expect(told).to_contain_text("it reaches the boat only when back")
    expect(toasts(manager).filter(has_text="ana stopped")).to_have_count(0)
