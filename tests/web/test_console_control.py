"""The console's control and its panels, in a real browser (as test_console_commands): a
field manager grants control on a phone, a lease that needs a live console lapses when it
closes, people are told when control changes, a go_to cancelled from the panel stops the
boat, the vehicle panel dates its readings, the manager revokes from the vehicle panel,
and "What happened" keeps its lines through a reconnect. A world of its own (the
module's), in file order."""

from __future__ import annotations

import re
import time
from typing import Any

from playwright.sync_api import expect

from tests.agent.procs import wait_until
from tests.web.conftest import Shots, World
from tests.web.console_helpers import (
    assert_labels_apart,
    command_item,
    label_boxes,
    log_in,
    marker,
    ms,
    newest_command,
    next_frames,
    position,
    screen_point,
)
from vehicle_client.geo import LocalFrame


def test_field_manager_grants_control_on_a_phone(
    world: World, open_console: Any, shots: Shots
) -> None:
    instance = world.instances["demo-usv-3"]
    world.as_user("ben", "POST", "/client/request_control", json={"instance_id": instance})
    page, _ = open_console(viewport=(390, 844), is_mobile=True, has_touch=True)
    log_in(page, "mia")
    expect(page.locator("#map")).to_be_visible()  # a phone opens on the map
    next_frames(page)
    for box in label_boxes(page):  # no label runs off the narrow screen
        assert box is not None and box["x"] >= 0 and box["x"] + box["width"] <= 390, box
    assert_labels_apart(page)
    shots(page, "phone-map")
    page.click('[data-tab="control"]')
    request = page.locator('form.request[data-user="ben"][data-vehicle="demo-usv-3"]')
    expect(request).to_be_visible()
    assert page.evaluate("document.documentElement.scrollWidth") <= 390  # no sideways scroll
    shots(page, "phone-requests")
    request.locator("select[name=duration]").select_option("900")
    # another request comes in meanwhile and the panel is drawn again: the manager's
    # choice stays (it was reset to 1 h, and the grant went out with that)
    other = {"instance_id": world.instances["demo-usv-1"]}
    world.as_user("ben", "POST", "/client/request_control", json=other)
    expect(page.locator('form.request[data-user="ben"][data-vehicle="demo-usv-1"]')).to_be_visible()
    expect(request.locator("select[name=duration]")).to_have_value("900")
    request.locator("button[type=submit]").tap()
    # ana holds it (since the world's start): the grant would end her lease, so it asks
    expect(page.locator("#confirm-title")).to_have_text("Give control of H2OmniX Charlie to ben?")
    ok = page.locator("#confirm-ok")
    expect(ok).to_be_enabled()
    ok.tap()
    lease = page.locator('li.lease[data-vehicle="demo-usv-3"]')
    expect(lease).to_contain_text("ben until")
    expect(lease.locator(".allows")).to_contain_text("allows ben to send")
    expect(request).to_have_count(0)
    control = world.fleet.call("POST", "/client/connect_instance", json={"instance_id": instance})
    held = control["instance"]["control"]
    assert held["holder"] == "ben" and held["granted_by"] == "mia"
    left = ms(held["expires_at"]) / 1000 - time.time()
    assert 850 < left <= 900, left
    box = lease.locator("button", has_text="Revoke").bounding_box()
    assert box is not None and box["height"] >= 32  # a thumb can hit it
    # Revoke asks first (the vehicle would hold station): cancelled here, nothing changes
    lease.locator("button", has_text="Revoke").tap()
    expect(page.locator("#confirm-title")).to_have_text("Revoke ben's control of H2OmniX Charlie?")
    page.locator("#confirm-cancel").tap()
    expect(page.locator("#confirm")).not_to_be_visible()
    expect(lease).to_contain_text("ben until")
    assert page.evaluate("document.documentElement.scrollWidth") <= 390
    shots(page, "phone-granted", full_page=True)
    # ben's other request (for the boat ana holds) is declined
    declined = page.locator('form.request[data-user="ben"][data-vehicle="demo-usv-1"]')
    declined.locator("input.reason").fill("divers in the water")
    declined.locator("input.reason").press("Enter")  # a reason's Enter grants nothing
    expect(declined).to_have_count(1)
    declined.locator("button.deny").tap()
    expect(declined).to_have_count(0)
    said = page.locator(
        'section.safety-log li[data-kind="control_deny"][data-vehicle="demo-usv-1"]'
    )
    expect(said.first).to_contain_text("request declined for ben")
    expect(said.first).to_contain_text("divers in the water")
    assert world.as_user("mia", "GET", "/client/control_requests")["requests"] == []
    page.click('[data-tab="map"]')  # back on the map: labels measured again, on the screen
    next_frames(page)
    next_frames(page)
    for box in label_boxes(page):
        assert box is not None and box["x"] >= 0 and box["x"] + box["width"] <= 390, box
    assert_labels_apart(page)


def test_a_lease_needing_a_live_console_lapses_when_it_closes(
    world: World, open_console: Any, shots: Shots
) -> None:
    """The manager grants ben demo-usv-3 on condition that his client stays alive; his open
    console keeps the lease (heartbeats) well past the timeout; when it closes, the lease
    lapses, the vehicle holds station and the manager's panel says why."""
    instance, timeout_s = world.instances["demo-usv-3"], 10
    manager, _ = open_console()
    log_in(manager, "mia")
    manager.click('[data-tab="control"]')
    grant = manager.locator("details.grant")
    grant.locator("summary").click()
    grant.locator("select[name=vehicle]").select_option("demo-usv-3")
    grant.locator("input[name=user]").fill("ben")
    grant.locator("select[name=duration]").select_option("900")
    grant.locator("select[name=liveness]").select_option(str(timeout_s))
    grant.locator("button[type=submit]").click()
    lease = manager.locator('li.lease[data-vehicle="demo-usv-3"]')
    # any console of ben's keeps it: said so (it said "this console", and a second
    # console left open elsewhere kept the lease of the one on the water alive)
    expect(lease.locator(".allows")).to_contain_text(
        f"every console of theirs is silent for {timeout_s} s; any console of theirs left open"
    )

    def lease_now() -> dict[str, Any] | None:
        body = {"instance_id": instance}
        return world.fleet.call("POST", "/client/connect_instance", json=body)["instance"][
            "control"
        ]

    held = lease_now()
    assert held and held["holder"] == "ben" and held["operator_timeout_s"] == timeout_s
    operator, _ = open_console()
    log_in(operator, "ben")
    operator.click('[data-tab="control"]')
    mine = operator.locator('li.lease[data-vehicle="demo-usv-3"]')
    expect(mine.locator(".allows")).to_contain_text(
        "this console keeps it alive while it is open, and so does any other you have open"
    )
    shots(operator, "operator-holds")
    # his vehicle panel says it too, and, while his console's link is lost, that it may
    # have lapsed (it said "you hold control until ..." as if nothing could end it)
    marker(operator, "demo-usv-3").click()
    operator.click('[data-tab="vehicle"]')
    live = operator.locator("#vehicle-pane .control-line .lapse-live")
    lost = operator.locator("#vehicle-pane .control-line .lapse-lost")
    expect(live).to_have_text(f" · lapses if all your consoles are silent for {timeout_s} s")
    expect(live).to_be_visible()
    expect(lost).to_be_hidden()
    operator.evaluate("document.getElementById('app').dataset.link = 'lost'")
    expect(lost).to_be_visible()
    expect(lost).to_have_text(
        f" · this console is out of contact: it lapses {timeout_s} s after the server last "
        "heard any console of yours, and may have"
    )
    expect(live).to_be_hidden()
    operator.evaluate("document.getElementById('app').dataset.link = 'live'")
    expect(live).to_be_visible()
    operator.click('[data-tab="control"]')
    # two timeouts pass with the console open: the lease is still ben's
    kept_until = time.monotonic() + 2 * timeout_s
    while time.monotonic() < kept_until:
        held = lease_now()
        assert held and held["holder"] == "ben", held
        operator.wait_for_timeout(500)  # the page runs (its heartbeats) meanwhile
    # logging out would end it too: asked first, in those words (cancelled here)
    operator.click("#logout")
    dialog = operator.locator("dialog[open]")
    expect(dialog).to_contain_text(
        f"Control of H2OmniX Charlie lapses {timeout_s} s after your last open console goes quiet"
    )
    operator.locator("#confirm-cancel").click()
    expect(dialog).to_have_count(0)
    operator.goto("about:blank")  # the console closes
    wait_until(lambda: lease_now() is None, "the lease lapsed once the console closed", 25)
    log = manager.locator("section.safety-log")
    for kind in ("hold_station", "control_expired"):
        item = log.locator(f'li[data-kind="{kind}"][data-vehicle="demo-usv-3"]').first
        expect(item).to_contain_text(re.compile("operator.silent"))
    # the routine mode changes of a mission (idle, remote) are not what happened
    expect(log.locator('li[data-kind="control_mode"]')).to_have_count(0)
    hold = newest_command(world, "demo-usv-3", "keep_station")
    assert hold is not None and hold["issued_by"] == "system", hold
    shots(manager, "manager-sees-hold")


def test_people_are_told_when_control_changes(
    world: World, open_console: Any, shots: Shots
) -> None:
    """Whatever tab is open: the operator when their control begins or ends, the field
    manager when someone asks for it (and the Control tab counts the requests)."""
    instance = world.instances["demo-usv-2"]
    operator, _ = open_console()
    log_in(operator, "ben")
    manager, _ = open_console()
    log_in(manager, "mia")
    tab = manager.locator('.tabs [data-tab="control"]')
    expect(tab).to_have_text("Control")
    marker(operator, "demo-usv-2").click()  # ben asks from the vehicle panel
    panel = operator.locator("#vehicle-pane")
    panel.locator("button", has_text="Request control").click()
    expect(panel.locator("button", has_text="Requested…")).to_be_disabled()  # not twice
    expect(manager.locator("#toasts")).to_contain_text("ben asks for control of H2OmniX Bravo")
    expect(tab).to_have_text("Control (1)")
    shots(manager, "manager-told-of-request")
    operator.reload()  # the console learns of its own request from the server again
    marker(operator, "demo-usv-2").click()
    asked = panel.locator("button", has_text="Requested…")
    expect(asked).to_be_disabled()
    expect(asked).to_have_attribute("title", re.compile(r"your request stands until \d\d:\d\d"))
    expect(panel.locator("button", has_text="Request control")).to_have_count(0)
    world.fleet.call("POST", "/client/revoke_control", json={"instance_id": instance})
    body = {"instance_id": instance, "user": "ben", "duration_s": 600}
    world.as_user("mia", "POST", "/client/grant_control", json=body)
    toasts = operator.locator("#toasts")
    expect(toasts).to_contain_text("you now hold control of H2OmniX Bravo (granted by mia)")
    expect(panel.locator("button", has_text="Release")).to_be_visible()
    expect(tab).to_have_text("Control")  # the request was answered by the grant
    world.as_user("mia", "POST", "/client/revoke_control", json={"instance_id": instance})
    expect(toasts).to_contain_text("your control of H2OmniX Bravo was revoked by mia")
    shots(operator, "operator-told")


def test_a_go_to_cancelled_in_the_console_stops_the_boat(
    world: World, open_console: Any, shots: Shots
) -> None:
    """ana cancels her go_to under way from the vehicle panel: it ends cancelled and the
    boat gives it up at once (its agent reports idle), though a go_to sends no ack on its
    way. Someone who may not cancel it is not offered the button."""
    vehicle, instance = "demo-usv-1", world.instances["demo-usv-1"]
    body = {"instance_id": instance, "user": "ana", "duration_s": 600}
    world.fleet.call("POST", "/client/grant_control", json=body)
    here = position(world, vehicle)
    far = LocalFrame(here["lat"], here["lon"]).to_latlon(2000.0, 0.0)
    page, _ = open_console()
    log_in(page, "ana")
    marker(page, vehicle).click()
    page.click('[data-tool="go_to"]')
    page.evaluate("([lat, lon]) => fleetConsole.map.map.panTo([lat, lon], {animate: false})", far)
    page.mouse.click(*screen_point(page, *far))
    sent = wait_until(lambda: newest_command(world, vehicle, "go_to"), "the go_to")
    item = command_item(page, sent["command_id"])
    expect(item).to_have_attribute("data-stage", "executing", timeout=30_000)
    watcher, _ = open_console()
    log_in(watcher, "ben")  # neither its issuer nor the holder: no cancel offered
    marker(watcher, vehicle).click()
    expect(command_item(watcher, sent["command_id"])).to_be_visible()
    expect(command_item(watcher, sent["command_id"]).locator("button")).to_have_count(0)
    item.locator("button", has_text="cancel").click()
    expect(item).to_have_attribute("data-stage", "cancelled")

    def mode() -> str:
        body = {"instance_id": instance}
        answer = world.fleet.call("POST", "/client/connect_instance", json=body)
        return str(answer["instance"]["control_mode"])

    wait_until(lambda: mode() == "idle" or None, "the boat to give up the go_to", 15)
    shots(page, "cancelled-under-way")


def test_the_vehicle_panel_says_how_old_its_readings_are_and_where_it_moves(
    world: World, open_console: Any
) -> None:
    """Course over ground from the trail beside the heading; the readings of a vehicle
    no longer online are greyed and dated."""
    page, _ = open_console()
    log_in(page, "mia")
    course = page.evaluate(
        """async () => {
            const { courseText } = await import("./js/panels.js");
            const t = Date.now();  // 10 m north and 10 m east in 5 s: 45 degrees
            const east = 10 / (111320 * Math.cos(60 * Math.PI / 180));
            const there = { t: t + 5000, lat: 60 + 10 / 111320, lon: 10 + east };
            return [
                courseText([{ t, lat: 60, lon: 10 }, there]),
                courseText([{ t, lat: 60, lon: 10 }, { t: t + 5000, lat: 60, lon: 10 }]),
            ];
        }"""
    )
    assert course == ["45 °", "\u2013"]  # at rest: no course (an en dash)
    marker(page, "demo-usv-3").click()
    panel = page.locator("#vehicle-pane")
    expect(panel.locator("dt", has_text="course")).to_be_visible()
    expect(panel.locator("dl.readings")).not_to_have_class(re.compile("stale"))
    page.evaluate(
        "fleetConsole.fleet.applyFleet({vehicles: [{vehicle_id: 'demo-usv-3', presence: 'stale'}]})"
    )
    expect(panel.locator("dl.readings")).to_have_class(re.compile(r"\bstale\b"))
    expect(panel.locator(".stale-note")).to_contain_text("the vehicle is stale")


def test_the_field_manager_revokes_from_the_vehicle_panel(world: World, open_console: Any) -> None:
    """Where the manager looks at the boat, not only on the Control tab: Revoke, asked
    first; an operator's panel offers no such button."""
    world.fleet.grant(world.instances["demo-usv-2"], "ben")
    page, _ = open_console()
    log_in(page, "mia")
    marker(page, "demo-usv-2").click()
    panel = page.locator("#vehicle-pane")
    expect(panel.locator(".control-line")).to_contain_text("ben holds control until")
    panel.locator("button", has_text="Revoke").click()
    expect(page.locator("#confirm-title")).to_have_text("Revoke ben's control of H2OmniX Bravo?")
    ok = page.locator("#confirm-ok")
    expect(ok).to_be_enabled()
    ok.click()
    expect(panel.locator(".control-line")).to_contain_text("nobody holds control")
    world.fleet.grant(world.instances["demo-usv-2"], "ben")
    other, _ = open_console()
    log_in(other, "ana")
    marker(other, "demo-usv-2").click()
    line = other.locator("#vehicle-pane .control-line")
    expect(line).to_contain_text("ben holds control")
    expect(line.locator("button", has_text="Revoke")).to_have_count(0)


def test_what_happened_keeps_its_lines_through_a_reconnect(world: World, open_console: Any) -> None:
    """A reconnect brings each vehicle's last 20 events again: "What happened" keeps what
    it listed before them (a stop, followed by 25 routine changes of the boat's name, was
    gone from it after the link came back)."""
    vehicle_id, instance = "demo-usv-2", world.instances["demo-usv-2"]
    world.fleet.grant(instance, "ben")
    page, _ = open_console()
    log_in(page, "mia")
    page.click('[data-tab="control"]')
    world.fleet.submit(world.tokens["ben"], instance, "stop", {})
    stop = page.locator(
        f'section.safety-log li[data-kind="command"][data-vehicle="{vehicle_id}"]'
    ).first
    expect(stop).to_contain_text("stop")
    name = world.fleet.call("GET", f"/api/vehicles/{vehicle_id}")["name"]
    for n in range(25):  # routine events, not listed: the server's last 20 are these
        body = {"name": f"{name} {n}" if n < 24 else name}
        world.fleet.call("PATCH", f"/api/vehicles/{vehicle_id}", json=body)
    page.wait_for_function(
        """id => fleetConsole.fleet.vehicles.get(id).events
             .filter(e => e.kind === 'vehicle_changed').length >= 25""",
        arg=vehicle_id,
        timeout=15_000,
    )
    page.evaluate(
        """() => {
             const told = fleetConsole.live.onEvent;
             window.snapshots = [];
             fleetConsole.live.onEvent = (topic, data, snapshot) => {
               if (snapshot) window.snapshots.push(topic);
               return told(topic, data, snapshot);
             };
             fleetConsole.live.reconnectNow();
           }"""
    )
    page.wait_for_function(
        "topic => window.snapshots.includes(topic)",
        arg=f"vehicle/{vehicle_id}/events",
        timeout=15_000,
    )
    next_frames(page)
    expect(stop).to_contain_text("stop")
