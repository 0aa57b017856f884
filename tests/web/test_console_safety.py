"""The console's safeguards, in a real browser (as test_console): what is typed in a number
field is read as the person meant it or refused, a double click does not act twice nor on
a button that appeared under the pointer, control changes hands only when asked twice and
its former holder is told, a vehicle out of reach does not look busy, and a phone's header
says who is logged in. A world of its own (the module's), in file order: ana holds every
vehicle at the start."""

from __future__ import annotations

import re
from typing import Any

import pytest
from playwright.sync_api import expect

from server.demo import VEHICLES
from tests.agent.procs import wait_until
from tests.web.conftest import PASSWORD, Shots, World, no_requests
from tests.web.test_console import (
    boxes_overlap,
    centre_on,
    log_in,
    marker,
    ms,
    newest_command,
    next_frames,
    position,
    screen_point,
)
from vehicle_client.geo import LocalFrame, distance_m

pytestmark = [pytest.mark.slow, pytest.mark.browser]


def test_a_decimal_comma_is_a_point_and_anything_else_is_refused(
    world: World, open_console: Any, shots: Shots
) -> None:
    """Chromium in English dropped the comma of "0,3" in a number field: the go_to went at
    3 m/s. "1e400" became an empty field, sent as the vehicle's own speed."""
    page, guard = open_console()
    log_in(page, "ana")
    vehicle = "demo-usv-2"
    start = position(world, vehicle)
    centre_on(page, start["lat"], start["lon"], 19)
    marker(page, vehicle).click()
    target = LocalFrame(start["lat"], start["lon"]).to_latlon(4.0, 6.0)
    speed, radius = page.locator("#opt-speed"), page.locator("#opt-radius")
    toasts = page.locator("#toasts")
    page.click('[data-tool="go_to"]')
    with no_requests(guard):
        for typed in ("1e400", "0x3", "1,5.2", "2 m/s", "Infinity"):
            speed.fill("")
            speed.press_sequentially(typed)  # as a person types it
            page.mouse.click(*screen_point(page, *target))
            expect(toasts).to_contain_text(f'"{typed}" is not a plain number')
        expect(page.locator("#tool-hint")).to_be_visible()  # the tool waits for a good one
        speed.fill("")
        speed.press_sequentially("25")
        page.mouse.click(*screen_point(page, *target))
        expect(toasts).to_contain_text("speed is 0.1 to 20 m/s, or empty for the vehicle's own")
        radius.fill("")
        radius.press_sequentially("-5")
        page.click("#hold")
        expect(toasts).to_contain_text("station radius is 1 to 500 m (not -5)")
    shots(page, "refused")
    speed.fill("")
    speed.press_sequentially("0,3")
    page.mouse.click(*screen_point(page, *target))
    sent = wait_until(lambda: newest_command(world, vehicle, "go_to"), "the go_to")
    assert sent["args"]["speed_mps"] == 0.3, sent["args"]
    assert distance_m(sent["args"]["lat"], sent["args"]["lon"], *target) < 0.5
    radius.fill("")
    radius.press_sequentially("2,5")
    page.click("#hold")

    def hold() -> dict[str, Any] | None:
        c = newest_command(world, vehicle, "keep_station")
        return c if c and "lat" not in c["args"] else None

    assert wait_until(hold, "Hold here")["args"] == {"radius_m": 2.5}
    shots(page, "sent")
    # a click that lands 20 km away (a zoomed-out map) asks first; cancelled: nothing sent
    far = LocalFrame(start["lat"], start["lon"]).to_latlon(20_000.0, 0.0)
    centre_on(page, far[0], far[1], 15)
    page.click('[data-tool="go_to"]')
    with no_requests(guard):
        page.mouse.click(*screen_point(page, *far))
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
    log_in(page, "ana")
    release = page.locator("#vehicle-pane button", has_text="Release")
    marker(page, "demo-usv-3").click()  # where its Vehicle tab has Release
    box = box_of(release)
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.click('[data-tab="fleet"]')
    vehicle = page.evaluate(
        "([x, y]) => document.elementFromPoint(x, y).closest('tr[data-vehicle]').dataset.vehicle",
        [x, y],
    )  # the fleet row at that point (a vehicle ana holds, as every one)
    instance = world.instances[vehicle]
    page.mouse.click(x, y)  # the double click's first click: the row's Vehicle tab opens
    expect(page.locator('.tabs [data-tab="vehicle"]')).to_have_attribute("aria-selected", "true")
    now = box_of(release)
    assert now["x"] < x < now["x"] + now["width"] and now["y"] < y < now["y"] + now["height"]
    page.mouse.down(click_count=2)  # its second, on the Release now under the pointer
    page.mouse.up(click_count=2)
    next_frames(page)
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
    assert lease_of(world, instance)["holder"] == "ana"
    release.click()
    ok = page.locator("#confirm-ok")
    expect(ok).to_be_enabled()
    ok.click()
    expect(page.locator("#vehicle-pane .control-line")).to_contain_text("nobody holds control")
    assert lease_of(world, instance) is None
    world.fleet.grant(instance, "ana")  # as it was, for the tests that follow


def test_control_given_over_its_holder_asks_first_and_the_holder_is_told(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A grant to someone while another holds the vehicle ends the holder's lease: the
    manager is asked first (it happened silently), and the holder is told (nothing said)."""
    instance = world.instances["demo-usv-1"]
    holder, _ = open_console()
    log_in(holder, "ana")
    page, guard = open_console()
    log_in(page, "mia")
    world.as_user("ben", "POST", "/client/request_control", json={"instance_id": instance})
    page.click('[data-tab="control"]')
    card = page.locator('form.request[data-user="ben"][data-vehicle="demo-usv-1"]')
    title, text = page.locator("#confirm-title"), page.locator("#confirm-text")
    card.locator("button[type=submit]").click()
    expect(title).to_have_text("Give control of H2OmniX Alpha to ben?")
    asked = r"^ana holds H2OmniX Alpha until \d\d:\d\d:\d\d; give control to ben instead\? "
    expect(text).to_have_text(re.compile(asked))
    shots(page, "asked")
    page.locator("#confirm-cancel").click()
    expect(page.locator("#confirm")).to_be_hidden()
    assert not [r for r in guard.requests if "/client/grant_control" in r]
    assert lease_of(world, instance)["holder"] == "ana"
    card.locator("button[type=submit]").click()
    ok = page.locator("#confirm-ok")
    expect(ok).to_be_enabled()
    ok.click()
    expect(page.locator('li.lease[data-vehicle="demo-usv-1"]')).to_contain_text("ben until")
    assert lease_of(world, instance)["holder"] == "ben"
    told = "control of H2OmniX Alpha passed to ben (granted by mia); it holds station"
    expect(holder.locator("#toasts")).to_contain_text(told)
    shots(holder, "holder-told")
    # the form that grants to anyone asks as well
    form = page.locator("details.grant")
    form.locator("summary").click()
    form.locator("select[name=vehicle]").select_option("demo-usv-2")
    form.locator("input[name=user]").fill("ben")
    form.locator("button[type=submit]").click()
    expect(title).to_have_text("Give control of H2OmniX Bravo to ben?")
    expect(text).to_have_text(re.compile(asked.replace("Alpha", "Bravo")))
    page.locator("#confirm-cancel").click()
    expect(page.locator("#confirm")).to_be_hidden()
    assert lease_of(world, world.instances["demo-usv-2"])["holder"] == "ana"
    world.fleet.grant(instance, "ana")


def lease_of(world: World, instance: str) -> Any:
    body = {"instance_id": instance}
    return world.fleet.call("POST", "/client/connect_instance", json=body)["instance"]["control"]


def box_of(locator: Any) -> dict[str, float]:
    """Where it is on the page (a panel drawn again on every sample replaces its buttons:
    one may be gone between finding and measuring it)."""
    return wait_until(locator.bounding_box, "it to be shown", 15)


def test_a_double_click_sends_once(world: World, open_console: Any, shots: Shots) -> None:
    """A double click on Request control asked twice, and one on a request card's Grant
    granted twice: a button that sends a call is disabled while the call is in flight."""
    vehicle, instance = "demo-usv-3", world.instances["demo-usv-3"]
    world.fleet.call("POST", "/client/revoke_control", json={"instance_id": instance})
    operator, asked = open_console()
    log_in(operator, "ben")
    marker(operator, vehicle).click()
    panel = operator.locator("#vehicle-pane")
    panel.locator("button", has_text="Request control").dblclick()
    expect(panel.locator("button", has_text="Requested…")).to_be_disabled()
    assert calls(asked, "/client/request_control") == 1
    manager, granted = open_console()
    log_in(manager, "mia")
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
    log_in(page, "ana")
    marker(page, "demo-usv-1").click()
    buttons = ["#hold", "#stop-selected", '#actions [data-tool="path"]']
    before = [box_of(page.locator(b)) for b in buttons]
    page.click('#actions [data-tool="path"]')
    expect(page.locator("#path-bar")).to_be_visible()
    assert [box_of(page.locator(b)) for b in buttons] == before
    page.click("#path-cancel")
    page.click('#actions [data-tool="go_to"]')
    expect(page.locator("#tool-hint")).to_be_visible()
    assert [box_of(page.locator(b)) for b in buttons] == before
    shots(page, "armed-nothing-moved")
    page.keyboard.press("Escape")


def calls(guard: Any, path: str) -> int:
    """How many times the page called ``path``."""
    return len([r for r in guard.requests if r.startswith("POST ") and r.endswith(path)])


def test_a_grant_says_which_boat_and_what_the_server_did(
    world: World, open_console: Any, shots: Shots
) -> None:
    """The toast said "control granted to ben until ..." (which boat?); a user mistyped
    read "no such user: no such user"; a grant for less than the holder has left, which the
    server ignores (a grant never shortens a lease), read as a plain success."""
    world.fleet.grant(world.instances["demo-usv-3"], "ben")  # for 1 h
    world.fleet.call(
        "POST", "/client/revoke_control", json={"instance_id": world.instances["demo-usv-1"]}
    )
    page, _ = open_console()
    log_in(page, "mia")
    page.click('[data-tab="control"]')
    form = page.locator("details.grant")
    form.locator("summary").click()
    toasts = page.locator("#toasts")

    def grant(vehicle: str, user: str, duration_s: int) -> None:
        form.locator("select[name=vehicle]").select_option(vehicle)
        form.locator("input[name=user]").fill(user)
        form.locator("select[name=duration]").select_option(str(duration_s))
        form.locator("button[type=submit]").click()

    grant("demo-usv-1", "bne", 3600)  # a name nobody knows: questioned first, then sent
    expect(form.locator("#grant-user-check")).to_contain_text("did you mean ben?")
    form.locator("button[type=submit]").click()
    expect(toasts).to_contain_text("grant refused: cannot grant control to bne: no such user")
    assert "no such user: no such user" not in toasts.inner_text()
    grant("demo-usv-3", "ben", 300)
    kept = r"ben already holds H2OmniX Charlie until \d\d:\d\d:\d\d; a grant never shortens a lease"
    expect(toasts).to_contain_text(re.compile(kept))
    shots(page, "not-shortened")
    grant("demo-usv-3", "ben", 86400)
    expect(toasts).to_contain_text(re.compile(r"control of H2OmniX Charlie granted to ben until "))


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
    here = position(world, "demo-usv-1")
    frame = LocalFrame(here["lat"], here["lon"])
    corners = [frame.to_latlon(e, n) for e, n in ((-15, 45), (15, 45), (15, 75), (-15, 75))]
    ring = [[o, a] for a, o in [*corners, corners[0]]]
    body = {"name": "reef", "kind": "no_go", "polygon": {"type": "Polygon", "coordinates": [ring]}}
    world.fleet.call("POST", "/api/zones", json=body)
    page, _ = open_console()
    log_in(page, "ana")
    expect(page.locator("path.zone-no_go")).to_have_count(1)
    centre_on(page, *frame.to_latlon(0, 0), 17)
    marker(page, "demo-usv-1").click()
    marker(page, "demo-usv-2").click(modifiers=["Shift"])
    expect(page.locator("#selection")).to_have_text("2 selected: H2OmniX Alpha, H2OmniX Bravo")
    page.click('#actions [data-tool="path"]')
    # one path for two boats is not planned (the planner keeps boats apart): said, and off
    expect(page.locator("#path-plan")).to_be_disabled()
    page.mouse.click(*screen_point(page, *frame.to_latlon(0, 60)))  # in the reef
    page.click("#path-send")
    refused = page.locator("#toasts .toast.error", has_text="follow_path NOT sent")
    expect(refused).to_contain_text(  # each boat by name, the reason once each
        re.compile(r"to any of them: H2OmniX Alpha: [^;]*reef[^;]*; H2OmniX Bravo: [^;]*reef")
    )
    shots(page, "refused-once")
    page.keyboard.press("Escape")
    page.click('#actions [data-tool="go_to"]')  # both to one point: queued, and said
    page.mouse.click(*screen_point(page, *frame.to_latlon(-40, -20)))  # clear of the boats
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
    page.evaluate(
        """() => {  // an hour that ended an hour before this server started
            const local = (t) => new Date(t - new Date(t).getTimezoneOffset() * 60000)
                .toISOString().slice(0, 19);
            document.getElementById("replay-from").value = local(Date.now() - 3 * 3600000);
            document.getElementById("replay-to").value = local(Date.now() - 2 * 3600000);
        }"""
    )
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
    log_in(page, "vic")
    expect(page.locator("#stop-all")).to_be_hidden()
    marker(page, "demo-usv-1").click()
    expect(page.locator("#selection")).to_be_hidden()
    expect(page.locator("#actions")).to_be_hidden()
    page, _ = open_console()
    log_in(page, "ben")
    marker(page, "demo-usv-1").click()
    page.click("#stop-selected")
    ok = page.locator("#confirm-ok")
    expect(ok).to_be_enabled()
    ok.click()
    stop = wait_until(lambda: newest_command(world, "demo-usv-1", "stop"), "the stop")
    lasts = ms(stop["expires_at"]) - ms(stop["issued_at"])
    assert lasts == 3_600_000, lasts


def test_a_vehicle_gone_offline_shows_its_stage_as_last_known(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A boat offline for 45 s still read "follow_path · executing" in orange on the map and
    in the table, its battery as live as the others'. (Last: its agent stays stopped.)"""
    vehicle, instance = "demo-usv-2", world.instances["demo-usv-2"]
    world.fleet.grant(instance, "ana")
    here = position(world, vehicle)
    far = LocalFrame(here["lat"], here["lon"]).to_latlon(0.0, 2000.0)
    world.fleet.submit(world.tokens["ana"], instance, "go_to", {"lat": far[0], "lon": far[1]})
    page, _ = open_console()
    log_in(page, "mia")
    label = marker(page, vehicle).locator(".chip")
    expect(label).to_have_text("go_to · executing", timeout=30_000)
    row = page.locator(f'#fleet-table tr[data-vehicle="{vehicle}"]')
    marker(page, vehicle).click()
    page.click('[data-tab="fleet"]')
    world.agents[[v[0] for v in VEHICLES].index(vehicle)].stop()  # out of reach
    expect(marker(page, vehicle)).to_have_attribute("data-presence", "offline", timeout=30_000)
    expect(label).to_have_text("go_to · executing (last known)")
    expect(label).to_have_class(re.compile(r"\blast-known\b"))
    expect(row.locator(".chip")).to_have_text("go_to · executing (last known)")
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
    log_in(page, "mia")
    bar, who = page.locator("header.bar"), page.locator("#who")
    expect(who).to_be_visible()
    expect(who).to_have_text("mia · manager")
    one_row = box_of(bar)["height"]
    assert one_row < 56, one_row
    marker(page, "demo-usv-1").tap()
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
        assert not boxes_overlap(box_of(toast), box_of(heading)), heading.inner_text()
    shots(page, "toast-clear-of-headings")
    world.server.stop(grace_s=5.0)
    expect(page.locator("#link")).to_have_attribute("data-state", "lost")
    expect(page.locator("#link")).to_contain_text("link lost")
    assert box_of(bar)["height"] == one_row, page.locator("#link").inner_text()
    assert page.evaluate("document.documentElement.scrollWidth") <= 390
    shots(page, "link-lost")
    world.server.start()
    expect(page.locator("#link")).to_have_attribute("data-state", "live", timeout=30_000)
    assert box_of(bar)["height"] == one_row
