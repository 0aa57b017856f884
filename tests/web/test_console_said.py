"""What a field manager's and her operators' test of the console found in what it says and
keeps, in a real browser (as test_console_wording): an empty replay left the old one on
the map (and Export saved the old window), identical refusals piled up, the server's
advice for one path sent to several boats could not be followed in the console, the
Replay tab ticked every boat whatever was selected, raw command types and event codes in
what people read, and link figures that contradicted each other; a vehicle's name is
shown as text whatever markup it holds. A world of its own (the module's), in file order: ana holds
every vehicle (the last test adds one that only zoe sees)."""

from __future__ import annotations

import re
from datetime import UTC, datetime
from typing import Any

import pytest
from playwright.sync_api import expect

from tests.web import console_helpers as console
from tests.web.conftest import PASSWORD, Shots, World
from tests.web.console_helpers import replay_up
from vehicle_client.geo import LocalFrame

pytestmark = [pytest.mark.slow, pytest.mark.browser]

CLOCK = r"\d\d:\d\d:\d\d"
TIMES = "\u00d7"  # the multiplication sign a count is written with ("5 times")


def replay_the_last_5_minutes(page: Any) -> None:
    """ana logs in and replays the last 5 minutes of every vehicle."""
    console.log_in(page, "ana")
    replay_up(page)
    page.click('[data-tab="replay"]')
    page.click('#replay-form [data-minutes="5"]')
    page.click("#replay-load")
    expect(page.locator("#replay-bar")).to_be_visible()


def ticked(page: Any) -> list[str]:
    return [
        box.get_attribute("value")
        for box in page.locator("#replay-vehicles input").all()
        if box.is_checked()
    ]


def test_a_replay_that_finds_nothing_clears_the_one_before(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A replay of the last 5 minutes, then one of a window with nothing in it: "Nothing was
    recorded..." under the form, and the old replay still on the map with its events and
    its Export buttons (which saved the old window)."""
    page, _ = open_console()
    replay_the_last_5_minutes(page)
    expect(page.locator(".vicon.replay")).to_have_count(3)
    expect(page.locator("#replay-export")).to_be_visible()
    shots(page, "first-replay")
    start, end = console.local_times(page, 4, 3)  # before this server started
    page.locator("#replay-from").fill(start)
    page.locator("#replay-to").fill(end)
    page.click("#replay-load")
    expect(page.locator("#replay-info")).to_contain_text("Nothing was recorded")
    expect(page.locator("#replay-bar")).to_be_hidden()
    expect(page.locator(".vicon.replay")).to_have_count(0)
    expect(page.locator("path.replay-track")).to_have_count(0)
    expect(page.locator("#replay-events li")).to_have_count(0)
    expect(page.locator("#replay-export")).to_be_hidden()
    for vehicle_id in console.ALL:  # the map is live again
        expect(console.marker(page, vehicle_id)).to_be_visible()
    shots(page, "old-replay-gone")


def test_the_same_refusal_again_is_counted_on_one_toast(
    world: World, open_console: Any, shots: Shots
) -> None:
    """ "Hold here" five times on a boat ben does not hold: three identical refusals and
    "+2 more". One toast now, counted: "x5" (a multiplication sign)."""
    page, _ = open_console()
    console.log_in(page, "ben")
    console.marker(page, "demo-usv-1").click()
    refused = page.locator("#toasts .toast", has_text="you do not hold control of H2OmniX Alpha")
    for n in range(1, 6):
        page.click("#hold")
        if n > 1:
            expect(refused.locator(".count")).to_have_text(f"{TIMES}{n}")
    expect(refused).to_have_count(1)
    expect(refused.locator(".msg")).to_have_text(
        "keep station refused: you do not hold control of H2OmniX Alpha"
    )
    expect(page.locator("#toasts .toast-more")).to_have_count(0)
    shots(page, "counted")
    page.click("#messages")  # the log says it once, counted too
    said = page.locator("#toast-log-list li", has_text="you do not hold control")
    expect(said).to_have_count(1)
    expect(said).to_contain_text(f"({TIMES}5)")
    page.keyboard.press("Escape")


def test_one_path_for_several_boats_is_told_in_the_console_s_words(
    world: World, open_console: Any, shots: Shots
) -> None:
    """ "note: 2 vehicles sent along one path, not planned: ...; give each its own waypoints,
    sending them one at a time", in the console's words."""
    page, _ = open_console()
    console.log_in(page, "ana")
    here = console.position(world, "demo-usv-1")
    frame = LocalFrame(here["lat"], here["lon"])
    console.centre_on(page, here["lat"], here["lon"], 17)
    console.marker(page, "demo-usv-1").click()
    console.marker(page, "demo-usv-3").click(modifiers=["Shift"])
    expect(page.locator("#selection")).to_have_text("2 selected: H2OmniX Alpha, H2OmniX Charlie")
    page.click('#actions [data-tool="path"]')
    for east, north in ((-40.0, -40.0), (-60.0, -40.0)):
        page.mouse.click(*console.screen_point(page, *frame.to_latlon(east, north)))
    expect(page.locator("#path-count")).to_have_text("2 waypoints")
    page.click("#path-send")
    note = page.locator("#toasts .toast.warn .msg")
    expect(note).to_have_text(
        re.compile(
            r"^note: H2OmniX Alpha and H2OmniX Charlie follow the same path and will come within "
            r"\d+ m of each other; send each its own path to keep them apart$"
        )
    )
    expect(page.locator("#toasts .toast.ok")).to_contain_text(
        "follow path queued for H2OmniX Alpha, H2OmniX Charlie"
    )
    shots(page, "path-note")


def test_the_replay_ticks_the_selected_boats_when_its_tab_opens(
    world: World, open_console: Any, shots: Shots
) -> None:
    """Every boat was ticked, whatever was selected: the boxes were drawn when the page
    loaded and never followed the selection."""
    page, _ = open_console()
    console.log_in(page, "ana")
    replay_up(page)
    console.marker(page, "demo-usv-2").click()
    page.click('[data-tab="replay"]')
    assert ticked(page) == ["demo-usv-2"]
    console.marker(page, "demo-usv-1").click()
    console.marker(page, "demo-usv-3").click(modifiers=["Shift"])
    page.click('[data-tab="replay"]')
    assert ticked(page) == ["demo-usv-1", "demo-usv-3"]
    page.locator('#replay-vehicles input[value="demo-usv-3"]').uncheck()  # by hand
    page.click('[data-tab="fleet"]')
    page.click('[data-tab="replay"]')
    assert ticked(page) == ["demo-usv-1"]  # kept while the selection is the same
    shots(page, "ticked-as-selected")


def test_commands_and_events_read_as_words(world: World, open_console: Any, shots: Shots) -> None:
    """ "allows ana to send follow_path, go_to, keep_station", "control grant ben until …",
    "failsafe applied by the vehicle version 0", "lapse when their client is [lapse:
    never]", a cancelled command's "by ana · by ana"."""
    vehicle, instance = "demo-usv-2", world.instances["demo-usv-2"]
    page, _ = open_console()
    console.log_in(page, "ana")
    page.click('[data-tab="control"]')
    allows = page.locator(f'li.lease[data-vehicle="{vehicle}"] .allows')
    expect(allows).to_contain_text(re.compile(r"allows you to send [a-z ,]*go to"))
    expect(allows).not_to_contain_text("_")

    body = {"instance_id": instance, "user": "ben", "duration_s": 600}
    world.as_user("mia", "POST", "/client/grant_control", json=body)
    world.fleet.grant(instance, "ana")  # back to her
    world.fleet.call("PUT", f"/api/vehicles/{vehicle}/failsafe", json={"after_s": 40.0})
    here = console.position(world, vehicle)
    far = LocalFrame(here["lat"], here["lon"]).to_latlon(0.0, 500.0)
    cid = world.fleet.submit(world.tokens["ana"], instance, "go_to", {"lat": far[0], "lon": far[1]})
    world.as_user("ana", "POST", "/client/cancel_command", json={"command_id": cid})

    console.marker(page, vehicle).click()
    events = page.locator("#vehicle-pane ol.events")
    expect(events).to_contain_text(re.compile(rf"control granted to ben until {CLOCK} \(by mia\)"))
    expect(events).to_contain_text(re.compile(r"control revoked from ben|control granted to ana"))
    expect(events).to_contain_text(
        re.compile(r"failsafe policy applied by the vehicle \(version \d+\)"), timeout=20_000
    )
    expect(events).not_to_contain_text(re.compile(r"control_|control grant |failsafe_"))
    item = console.command_item(page, cid)
    expect(item).to_have_attribute("data-stage", "cancelled")
    expect(item.locator("b")).to_have_text("go to")
    expect(item.locator("small")).to_have_text(re.compile(rf"^{CLOCK} by ana$"))
    shots(page, "panel-in-words")

    page.click('[data-tab="replay"]')
    page.click('#replay-form [data-minutes="5"]')
    page.click("#replay-load")
    expect(page.locator("#replay-bar")).to_be_visible()
    lines = page.locator("#replay-events")
    granted = re.compile(rf"H2OmniX Bravo control granted to ben until {CLOCK}")
    expect(lines).to_contain_text(granted)
    expect(lines).to_contain_text("go to cancelled")
    expect(lines).not_to_contain_text(re.compile(r"control grant |go_to|keep_station"))
    page.click("#replay-exit")
    world.fleet.call("PUT", f"/api/vehicles/{vehicle}/failsafe", json={})

    manager, _ = open_console()
    console.log_in(manager, "mia")
    manager.click('[data-tab="control"]')
    grant = manager.locator("details.grant")
    grant.locator("summary").click()
    lapse = grant.locator("label", has=manager.locator("select[name=liveness]"))
    expect(lapse).to_contain_text("if their client falls silent:")
    expect(lapse.locator("option").first).to_have_text("never lapses")
    expect(lapse.locator("option").nth(2)).to_have_text("lapses after 30 s silent")
    shots(manager, "grant-form-words")


def test_the_last_minutes_take_in_what_happened_since_the_tab_opened(
    world: World, open_console: Any
) -> None:
    """ "The last 5 minutes" ended when the Replay tab opened, cut down to its whole second:
    a go to cancelled after a replay, with the tab still open, was not in the next replay
    asked a moment later."""
    vehicle, instance = "demo-usv-1", world.instances["demo-usv-1"]
    page, _ = open_console()
    replay_the_last_5_minutes(page)
    cancelled = page.locator("#replay-events li", has_text="H2OmniX Alpha command go to cancelled")
    before = cancelled.count()
    shown_end = page.locator("#replay-to").input_value()
    here = console.position(world, vehicle)
    near = LocalFrame(here["lat"], here["lon"]).to_latlon(0.0, 50.0)
    cid = world.fleet.submit(
        world.tokens["ana"], instance, "go_to", {"lat": near[0], "lon": near[1]}
    )
    world.as_user("ana", "POST", "/client/cancel_command", json={"command_id": cid})
    page.click("#replay-load")
    expect(cancelled).to_have_count(before + 1)
    assert page.locator("#replay-to").input_value() >= shown_end  # the form says what was asked
    page.click("#replay-exit")


def test_the_link_s_figures_never_contradict_each_other(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A panel said "19 ms one way · 13 ms round trip". The view is handed to the page as
    the fleet topic would (the simulated boats on loopback measure well under a
    millisecond, and their figures are told again only when they move by 5 ms)."""
    page, _ = open_console()
    console.log_in(page, "ana")
    console.marker(page, "demo-usv-3").click()
    expect(page.locator("#vehicle-pane dd.link-delay")).to_be_visible()

    def shown(one_way: float, rtt: float) -> list[str]:
        """The panel's and the fleet list's link figures drawn from this view, read at
        once (the boat's own figures, told when they move, would replace it)."""
        return list(
            page.evaluate(
                """async ([one, rtt]) => {
                     fleetConsole.fleet.applyFleet({vehicles: [{
                       vehicle_id: "demo-usv-3", link_delay_ms: one, link_rtt_ms: rtt}]}, false);
                     const frame = () => new Promise((r) => requestAnimationFrame(r));
                     await frame();
                     await frame();
                     const row = '#fleet-table tr[data-vehicle="demo-usv-3"] .link-delay';
                     return [document.querySelector('#vehicle-pane dd.link-delay').textContent,
                             document.querySelector(row).textContent];
                   }""",
                [one_way, rtt],
            )
        )

    # the vehicle's clock estimate off by more than the delay: the one-way figure is left out
    assert shown(19.0, 13.0) == ["13 ms round trip", "link 13 ms"]
    assert shown(5.0, 13.0)[0] == "13 ms round trip · 5.0 ms one way"
    shots(page, "link-figures")


def test_a_speed_above_a_boat_s_top_speed_is_said(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A go to at 3 m/s was queued without a word; the boat reports a top speed of 0.5
    m/s (its max_speed_mps parameter) and went at that."""
    page, _ = open_console()
    console.log_in(page, "ana")
    here = console.position(world, "demo-usv-3")
    console.centre_on(page, here["lat"], here["lon"], 17)
    console.marker(page, "demo-usv-3").click()
    page.fill("#opt-speed", "3")
    page.click('#actions [data-tool="go_to"]')
    there = LocalFrame(here["lat"], here["lon"]).to_latlon(30.0, -30.0)
    page.mouse.click(*console.screen_point(page, *there))
    expect(page.locator("#toasts .toast.warn .msg")).to_have_text(
        "note: H2OmniX Charlie's top speed is 0.5 m/s: it will go at that, not 3 m/s"
    )
    expect(page.locator("#toasts .toast.ok")).to_contain_text("go to queued for H2OmniX Charlie")
    shots(page, "top-speed")
    page.fill("#opt-speed", "")


def test_a_vehicle_an_admin_renames_is_renamed_in_the_open_console(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A vehicle registered under the wrong name is put right by an admin (``PATCH
    /api/vehicles/...``): ana's open console shows the new name on its row and its
    marker at once, and its panel says what was changed."""
    page, _ = open_console()
    console.log_in(page, "ana")
    here = console.position(world, "demo-usv-3")
    console.centre_on(page, here["lat"], here["lon"], 17)
    console.marker(page, "demo-usv-3").click()
    world.fleet.call("PATCH", "/api/vehicles/demo-usv-3", json={"name": "Charlie Survey"})
    try:
        row = page.locator('#fleet-table tr[data-vehicle="demo-usv-3"]')
        expect(row).to_contain_text("Charlie Survey")
        expect(row).not_to_contain_text("H2OmniX Charlie")
        label = console.marker(page, "demo-usv-3").locator(".vlabel")
        expect(label).to_contain_text("Charlie Survey")
        expect(label).not_to_contain_text("H2OmniX")
        expect(page.locator("#vehicle-pane ol.events")).to_contain_text(
            "vehicle record changed: name H2OmniX Charlie \u2192 Charlie Survey"
        )
        shots(page, "renamed")
    finally:
        world.fleet.call("PATCH", "/api/vehicles/demo-usv-3", json={"name": "H2OmniX Charlie"})


def test_a_sample_dated_years_ahead_does_not_hold_the_marker(
    world: World, open_console: Any
) -> None:
    """A boat's clock glitch (a sample dated 2099) was taken as its newest position: the
    marker stayed there, as no later sample could replace it, and the trail ran to it."""
    vehicle_id = "clock-usv"  # seen only by yan: the other tests' people still see three
    body = {"vehicle_id": vehicle_id, "name": "Clock", "vehicle_type": "usv"}
    token = world.fleet.call("POST", "/api/vehicles", json=body)["token"]
    started = world.fleet.call(
        "POST", "/upper/start_instance", token, json={**body, "capabilities": ["stop"]}
    )

    def report(seq: int, when: datetime, lat: float) -> None:
        sample = {"seq": seq, "ts": when.isoformat(), "lat": lat, "lon": 15.44}
        world.fleet.call(
            "POST", "/upper/update_param", token,
            json={"instance_id": started["instance_id"], "samples": [sample]},
        )  # fmt: skip

    report(1, datetime.now(UTC), 43.930)
    user = {"username": "yan", "role": "viewer", "vehicles": [vehicle_id], "password": PASSWORD}
    world.fleet.call("POST", "/api/users", json=user)
    page, _ = open_console()
    console.log_in(page, "yan", markers=1)
    report(2, datetime(2099, 12, 31, tzinfo=UTC), 43.950)  # the glitch, far to the north
    report(3, datetime.now(UTC), 43.931)
    page.wait_for_function(
        "() => fleetConsole.fleet.vehicles.get('clock-usv').view.position.seq === 3",
        timeout=15_000,
    )
    far = page.evaluate(
        "() => fleetConsole.fleet.vehicles.get('clock-usv').trail"
        ".filter((p) => p.lat > 43.94).length"
    )
    assert far == 0, "the trail runs to the glitch"


def test_a_name_with_markup_is_shown_as_text_and_no_inline_script_runs(
    world: World, open_console: Any
) -> None:
    """A vehicle chooses its display name: markup in it is text in every label, and the
    page's policy would refuse an inline handler even if one slipped through."""
    name = '<img src=x onerror="window.__pwned=1">'
    vehicle_id = "markup-usv"  # seen only by zoe: the other tests' people still see three
    body = {"vehicle_id": vehicle_id, "name": name, "vehicle_type": "usv"}
    token = world.fleet.call("POST", "/api/vehicles", json=body)["token"]
    started = world.fleet.call(
        "POST", "/upper/start_instance", token, json={**body, "capabilities": ["stop"]}
    )
    sample = {"seq": 1, "ts": datetime.now(UTC).isoformat(), "lat": 43.93, "lon": 15.44}
    world.fleet.call(
        "POST", "/upper/update_param", token,
        json={"instance_id": started["instance_id"], "params": {}, "samples": [sample]},
    )  # fmt: skip
    user = {"username": "zoe", "role": "operator", "vehicles": [vehicle_id], "password": PASSWORD}
    world.fleet.call("POST", "/api/users", json=user)
    page, guard = open_console()
    console.log_in(page, "zoe", markers=1)
    expect(console.marker(page, vehicle_id).locator(".vlabel b")).to_have_text(name)
    console.marker(page, vehicle_id).click()
    expect(page.locator("#vehicle-pane")).to_contain_text(name)
    blocked = "Content Security Policy"
    with page.expect_console_message(lambda m: blocked in m.text):
        fired = page.evaluate(  # what an unescaped label would do
            """n => new Promise(done => {
                const d = document.createElement("div");
                d.innerHTML = n;  // its inline handler, set before this listener, runs first
                d.querySelector("img").addEventListener("error", () => done(true));
                document.body.append(d);
            })""",
            name,
        )
    assert fired is True and page.evaluate("window.__pwned") is None
    refused = [e for e in guard.errors if blocked in e]
    assert len(refused) == 1 and "script-src" in refused[0]
    guard.errors.remove(refused[0])  # the refusal this test caused: not a fault of the page
