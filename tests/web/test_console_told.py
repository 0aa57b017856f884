"""What the people at the consoles are told without looking for it, in a real browser (as
test_console_watch): a stop someone else sent to the boat you command, and who sent it;
an alarm, whatever tab is open; a revoke of a boat out of contact (the hold waits for
it), a command that expired unacknowledged, the boat back online; control that
ended while your console was out of contact; a command that failed on the boat, live or
while the console was out of contact; "went offline" taken down when the boat is back.
Each was found missing by a field test. A world of its own (the module's): an agent is
stopped and started again."""

from __future__ import annotations

import re
from typing import Any

import pytest
from playwright.sync_api import expect

from server.demo import VEHICLES
from tests.agent.procs import wait_until
from tests.web.conftest import Shots, World
from tests.web.console_helpers import centre_on, command_item, lease_of, log_in, marker

pytestmark = [pytest.mark.slow, pytest.mark.browser]


def toasts(page: Any) -> Any:
    return page.locator("#toasts .toast .msg")


def vehicle_view(world: World, vehicle_id: str) -> dict[str, Any]:
    return dict(world.fleet.call("GET", f"/api/vehicles/{vehicle_id}"))


def test_a_stop_someone_else_sent_is_told_to_whoever_commands_the_boat(
    world: World, open_console: Any, shots: Shots
) -> None:
    page, _ = open_console()
    log_in(page, "ana")  # she holds control of every boat (the world's grants)
    marker(page, "demo-usv-1").click()
    page.click('[data-tab="vehicle"]')
    cid = world.fleet.submit(world.tokens["mia"], world.instances["demo-usv-1"], "stop", {})
    expect(toasts(page).filter(has_text="mia stopped H2OmniX Alpha")).to_have_count(1)
    # and the boat's command list says who sent it, as it comes
    expect(command_item(page, cid)).to_contain_text("by mia")
    shots(page, "stop-told")
    # gone after its time, the message can be read again (Messages, in the header)
    page.click("#messages")
    expect(page.locator("#toast-log-list")).to_contain_text("mia stopped H2OmniX Alpha")
    page.keyboard.press("Escape")


def test_an_alarm_is_a_toast_whatever_tab_is_open(
    world: World, open_console: Any, shots: Shots
) -> None:
    page, _ = open_console()
    log_in(page, "ana")
    page.click('[data-tab="fleet"]')
    # The simulated boats run on 100 % or less: a threshold of 100 % is a low battery.
    world.fleet.call("PUT", "/api/vehicles/demo-usv-3/failsafe", json={"low_battery_pct": 100.0})
    said = toasts(page).filter(has_text=re.compile(r"^H2OmniX Charlie: battery low"))
    expect(said).to_have_count(1, timeout=15_000)
    shots(page, "alarm-told")
    world.fleet.call("PUT", "/api/vehicles/demo-usv-3/failsafe", json={})
    # the alarm ended: its toast goes with it, well before its 12 s are up
    expect(said).to_have_count(0, timeout=5_000)


def test_a_boat_out_of_contact_revoked_expired_and_back_is_told_as_it_is(
    world: World, open_console: Any, shots: Shots
) -> None:
    vehicle = "demo-usv-2"
    agent = world.agents[[v[0] for v in VEHICLES].index(vehicle)]
    manager, _ = open_console(viewport=(390, 844))
    log_in(manager, "mia")
    operator, _ = open_console()
    log_in(operator, "ana")
    agent.stop()  # out of contact
    wait_until(lambda: vehicle_view(world, vehicle)["presence"] == "offline", "Bravo offline")

    # a command that expires unacknowledged is told to its sender
    world.fleet.submit(world.tokens["ana"], world.instances[vehicle], "keep_station", {}, ttl_s=2)
    expired = toasts(operator).filter(has_text="keep station for H2OmniX Bravo expired")
    expect(expired).to_have_count(1, timeout=20_000)
    expect(expired).to_contain_text("never acknowledged")

    # the revoke says the hold waits for the boat, not that it holds station at once
    manager.click('[data-tab="control"]')
    lease = manager.locator('li.lease[data-vehicle="demo-usv-2"]')
    lease.get_by_role("button", name="Revoke").click()
    dialog = manager.locator("dialog[open]")
    expect(dialog).to_contain_text("H2OmniX Bravo is offline: the hold is queued")
    shots(manager, "revoke-offline")
    dialog.get_by_role("button", name="Revoke").click()
    said = toasts(manager).filter(has_text="control of H2OmniX Bravo revoked; H2OmniX Bravo is")
    expect(said).to_have_count(1)

    agent.start()  # back in contact
    back = toasts(manager).filter(has_text="H2OmniX Bravo is back online")
    expect(back).to_have_count(1, timeout=60_000)
    shots(manager, "back-online")


def test_control_that_ended_while_the_console_was_out_of_contact_is_told(
    world: World, open_console: Any, shots: Shots
) -> None:
    page, _ = open_console()
    log_in(page, "ana")
    instance = world.instances["demo-usv-3"]
    assert lease_of(world, instance)["holder"] == "ana"
    page.context.set_offline(True)  # a phone out of signal: its socket neither answers
    world.fleet.call("POST", "/client/revoke_control", world.tokens["mia"], json={
        "instance_id": instance})  # fmt: skip
    expect(page.locator("#link")).to_have_attribute("data-state", "lost", timeout=35_000)
    page.context.set_offline(False)
    expect(page.locator("#link")).to_have_attribute("data-state", "live", timeout=30_000)
    said = toasts(page).filter(has_text="you no longer hold control of H2OmniX Charlie")
    expect(said).to_have_count(1, timeout=10_000)
    shots(page, "lapse-told")


def test_logging_out_while_holding_control_asks_first_and_ends_the_session(
    world: World, open_console: Any, shots: Shots
) -> None:
    page, _ = open_console()
    log_in(page, "ana")  # with her password: a session token
    token = page.evaluate("() => window.fleetConsole.api.token")
    # her leases were granted with no lapse on silence: the card and the question say so
    page.click('[data-tab="control"]')
    allows = page.locator('li.lease[data-vehicle="demo-usv-1"] .allows')
    expect(allows).to_contain_text(
        "It never lapses on silence: it stays yours with your console closed"
    )
    page.click("#logout")
    dialog = page.locator("dialog[open]")
    expect(dialog).to_contain_text("Log out while you hold control of H2OmniX Alpha")
    expect(dialog).to_contain_text("Control stays yours until it ends, with nobody at this")
    expect(dialog).not_to_contain_text("lapse")
    shots(page, "logout-asks")
    dialog.get_by_role("button", name="Log out").click()
    expect(page.locator("#login")).to_be_visible()
    with pytest.raises(AssertionError, match="401"):
        world.fleet.call("GET", "/api/me", token)


def test_a_lease_about_to_end_is_told_a_minute_before(
    world: World, open_console: Any, shots: Shots
) -> None:
    page, _ = open_console()
    log_in(page, "ben")
    body = {"instance_id": world.instances["demo-usv-3"], "user": "ben", "duration_s": 65}
    world.fleet.call("POST", "/client/grant_control", world.tokens["mia"], json=body)
    said = toasts(page).filter(has_text="your control of H2OmniX Charlie ends at")
    expect(said).to_have_count(1, timeout=20_000)
    expect(said).to_contain_text("ask for more in time")
    shots(page, "lease-ending")


def test_all_boats_brings_every_boat_back_into_view(
    world: World, open_console: Any, shots: Shots
) -> None:
    page, _ = open_console(viewport=(390, 844))  # a phone: no wheel to zoom out with
    log_in(page, "mia")
    here = world.fleet.position(world.instances["demo-usv-1"])
    centre_on(page, here["lat"], here["lon"], 21)
    view = page.locator("#map").bounding_box()
    assert view is not None

    def inside(vehicle_id: str) -> bool:
        box = marker(page, vehicle_id).bounding_box()
        return box is not None and (
            view["x"] <= box["x"] + box["width"] / 2 <= view["x"] + view["width"]
            and view["y"] <= box["y"] + box["height"] / 2 <= view["y"] + view["height"]
        )

    assert not all(inside(v[0]) for v in VEHICLES)  # zoomed in on one
    page.get_by_role("button", name="All boats").click()
    wait_until(lambda: all(inside(v[0]) for v in VEHICLES), "every boat in view", 10)
    shots(page, "all-boats")


def test_a_command_that_failed_on_the_boat_is_told_live_and_after_a_reconnect(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A go_to the boat's agent reported failed ("agent restarted") was shown only in the
    panels, and not at all when it failed while the console was out of contact with the
    server (found in a field test: the server restarted, and the agent with it)."""
    vehicle = "demo-usv-1"
    agent = world.agents[[v[0] for v in VEHICLES].index(vehicle)]
    instance = world.instances[vehicle]
    page, _ = open_console()
    log_in(page, "ana")  # she holds Alpha (the world's grants)

    def status(command_id: str) -> str:
        answer = world.fleet.call("GET", "/client/get_fbmessage", params={"instance_id": instance})
        return str(next(c["status"] for c in answer["commands"] if c["command_id"] == command_id))

    def go_to_then_restart(live: bool) -> None:
        here = world.fleet.position(instance)
        target = {"lat": here["lat"] + 0.005, "lon": here["lon"]}  # half a kilometre north
        cid = world.fleet.submit(world.tokens["ana"], instance, "go_to", target)
        wait_until(lambda: status(cid) in ("accepted", "executing"), "the go_to under way", 20)
        if not live:
            page.evaluate("fleetConsole.live.stop()")  # this console out of contact
        agent.stop()
        agent.start()
        wait_until(lambda: status(cid) == "failed", "the go_to failed", 30)
        if not live:
            page.evaluate("fleetConsole.live.start()")
            expect(page.locator("#link")).to_have_attribute("data-state", "live")

    told = toasts(page).filter(has_text="go to for H2OmniX Alpha failed: agent restarted")
    go_to_then_restart(live=True)
    expect(told).to_have_count(1, timeout=10_000)
    shots(page, "failed-live")
    page.evaluate("document.querySelectorAll('#toasts .toast').forEach(t => t.dismiss())")
    expect(told).to_have_count(0)
    go_to_then_restart(live=False)
    expect(told).to_have_count(1, timeout=10_000)
    shots(page, "failed-while-away")


def test_went_offline_is_taken_down_when_the_boat_is_back(
    world: World, open_console: Any, shots: Shots
) -> None:
    """ "went offline during go to" stayed up beside "is back online", saying the opposite."""
    vehicle = "demo-usv-1"
    agent = world.agents[[v[0] for v in VEHICLES].index(vehicle)]
    instance = world.instances[vehicle]
    page, _ = open_console()
    log_in(page, "ana")
    here = world.fleet.position(instance)
    target = {"lat": here["lat"] + 0.005, "lon": here["lon"]}
    cid = world.fleet.submit(world.tokens["ana"], instance, "go_to", target)
    marker(page, vehicle).click()
    expect(command_item(page, cid)).to_contain_text(re.compile("acked|executing"))
    agent.stop()
    gone = toasts(page).filter(has_text="H2OmniX Alpha went offline during go to")
    expect(gone).to_have_count(1, timeout=60_000)
    agent.start()
    back = toasts(page).filter(has_text="H2OmniX Alpha is back online")
    expect(back).to_have_count(1, timeout=60_000)
    expect(gone).to_have_count(0)
    shots(page, "back-not-offline")


def test_boats_gone_out_of_contact_while_the_console_was_are_said_after_it(
    world: World, open_console: Any, shots: Shots
) -> None:
    """The server restarted (a field test): the console said "the view is up to date again"
    and nothing of the boats it found offline in its first snapshot, only grey markers."""
    vehicle = "demo-usv-3"
    agent = world.agents[[v[0] for v in VEHICLES].index(vehicle)]

    def presence() -> str:
        return str(world.fleet.call("GET", f"/api/vehicles/{vehicle}")["presence"])

    page, _ = open_console()
    log_in(page, "mia")
    page.evaluate("fleetConsole.live.stop()")  # this console out of contact
    agent.stop()
    try:
        wait_until(lambda: presence() == "offline", "Charlie offline", 60)
        page.evaluate("fleetConsole.live.start()")
        expect(page.locator("#link")).to_have_attribute("data-state", "live")
        said = toasts(page).filter(has_text="H2OmniX Charlie")
        expect(said.filter(has_text=re.compile(r"out of contact|went offline"))).to_have_count(1)
        expect(said.first).to_contain_text(re.compile(r"last heard \d\d:\d\d:\d\d"))
        shots(page, "offline-said-after-reconnect")
    finally:
        agent.start()
        wait_until(lambda: presence() == "online", "Charlie back", 60)
