"""Zones in what people read, in a real browser (as test_console_wording): a zone drawn,
renamed and removed reads as words in a vehicle's events and the replay's list, and the
replay draws the zones and the obstacles of its cursor's time; a zone or an obstacle
drawn, changed or removed is told; a failsafe and a presence found late read as words. A
world of its own (the module's)."""

from __future__ import annotations

import re
import time
from typing import Any

import pytest
from playwright.sync_api import expect

from tests.agent.procs import wait_until
from tests.web import console_helpers as console
from tests.web.conftest import Shots, World
from tests.web.console_helpers import ms, replay_up
from vehicle_client.geo import LocalFrame

pytestmark = [pytest.mark.slow, pytest.mark.browser]


def test_a_zone_drawn_changed_and_removed_reads_as_words(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A zone an admin drew, renamed and removed read, in the vehicle panel's recent events
    and the replay's list, as the event's data: "zones changed zone id z-590c… · name survey
    box · kind operating_area · action created · version 2"."""
    vehicle = "demo-usv-3"
    here = console.position(world, vehicle)
    far = LocalFrame(here["lat"], here["lon"])  # 2 km off: nothing sails near it
    ring = [far.to_latlon(east, north) for east, north in ((0, 2000), (50, 2000), (50, 2050))]
    body = {
        "name": "Far rocks",
        "kind": "no_go",
        "vehicles": [vehicle],
        "polygon": console.polygon(ring),
    }
    zone_id = world.fleet.call("POST", "/api/zones", json=body)["zone_id"]
    world.fleet.call("PATCH", f"/api/zones/{zone_id}", json={"name": "Outer rocks"})
    world.fleet.call("DELETE", f"/api/zones/{zone_id}")

    page, _ = open_console()
    console.log_in(page, "mia")
    console.marker(page, vehicle).click()
    page.click('[data-tab="vehicle"]')
    events = page.locator("#vehicle-pane ol.events")
    expect(events).to_contain_text("zones changed: no-go zone Far rocks created by admin")
    expect(events).to_contain_text("zones changed: no-go zone Outer rocks changed by admin")
    expect(events).to_contain_text("zones changed: no-go zone Outer rocks deleted by admin")
    expect(events).not_to_contain_text(re.compile(r"zone id|no_go|version \d"))
    shots(page, "zones-in-words")

    replay_up(page)
    page.click('[data-tab="replay"]')
    page.click('#replay-form [data-minutes="5"]')
    page.click("#replay-load")
    expect(page.locator("#replay-bar")).to_be_visible()
    lines = page.locator("#replay-events")
    expect(lines).to_contain_text("H2OmniX Charlie zones changed: no-go zone Far rocks created")
    expect(lines).not_to_contain_text(re.compile(r"zone id|no_go|version \d"))
    # the map draws the zones of the cursor's time, said under the summary: the rocks are
    # on it from their drawing to their removal, and not before nor after
    expect(page.locator("#replay-info .zones-then")).to_have_text(
        re.compile(r"^Zones are drawn as they were at the cursor's time: ([3-9]|\d\d+) "
                   r"zone changes in this window\.$")
    )  # fmt: skip
    no_go = "() => document.querySelectorAll('#map path.zone-no_go').length"
    lines.locator("li", has_text="Far rocks created").first.click()
    with_rocks = page.evaluate(no_go)
    lines.locator("li", has_text="Outer rocks deleted").first.click()
    page.wait_for_function(f"() => ({no_go})() === {with_rocks - 1}")
    shots(page, "replay-zones-in-words")
    # the timeline marks each change of the zones once (not once per boat), in words (the
    # three, a moment apart, are one mark), and a click on it moves the cursor there
    marks = page.locator("#timeline-changes .change-mark.c-zone")
    said = [(m.get_attribute("title") or "").splitlines() for m in marks.all()]
    (group,) = [i for i, lines in enumerate(said) if any("rocks" in x for x in lines)]
    assert [re.sub(r"^\S+ ", "", x) for x in said[group] if "rocks" in x] == [
        "no-go zone Far rocks drawn",
        "no-go zone Outer rocks changed (was Far rocks)",
        "no-go zone Outer rocks removed",
    ], said
    page.evaluate("() => fleetConsole.replay.seek(fleetConsole.replay.end)")
    page.wait_for_function(f"() => ({no_go})() === {with_rocks - 1}")
    marks.nth(group).click()
    page.wait_for_function(f"() => ({no_go})() === {with_rocks}")
    shots(page, "replay-zone-marks")
    # an event's tick moves the cursor to it, as its line does (a click on it did nothing)
    page.locator("#timeline-ticks .tick").last.click()
    assert page.evaluate("fleetConsole.replay.cursor") == page.evaluate(
        "fleetConsole.replay.events.at(-1).t"
    )
    page.click("#replay-exit")


def test_a_replay_draws_the_obstacles_of_its_cursors_time(
    world: World, open_console: Any, shots: Shots
) -> None:
    """The replay drew the obstacles of now (found by a field-manager test): one removed
    since was missing from the time it stood, and one drawn later stood there before it."""
    here = console.position(world, "demo-usv-1")
    near = LocalFrame(here["lat"], here["lon"])
    ring = [near.to_latlon(east, north) for east, north in ((80, 0), (120, 0), (120, 40))]
    body = {
        "name": "Old wreck",
        "polygon": console.polygon(ring),
    }
    made = world.fleet.call("POST", "/api/obstacles", json=body)
    drawn = ms(made["created_at"])
    wait_until(lambda: time.time() * 1000 > drawn + 1500, "the wreck to stand a while", 5)
    world.fleet.call("DELETE", f"/api/obstacles/{made['obstacle_id']}")

    page, _ = open_console()
    console.log_in(page, "mia")
    wrecks = "() => document.querySelectorAll('#map path.obstacle').length"
    expect(page.locator("#map path.obstacle")).to_have_count(0)  # removed: not drawn now
    replay_up(page)
    page.click('[data-tab="replay"]')
    page.click('#replay-form [data-minutes="5"]')
    page.click("#replay-load")
    expect(page.locator("#replay-bar")).to_be_visible()
    expect(page.locator("#replay-info .obstacles-then")).to_have_text(
        "Obstacles are drawn as they were at the cursor's time: 2 obstacle changes in this window."
    )
    # one mark on the timeline (1.5 s apart in 5 min) says both, and goes to the first
    # its placing and its removal marked on the timeline (with any change a moment
    # before them: one mark, each click going on to the next of its changes)
    mark = page.locator("#timeline-changes .change-mark[title*='Old wreck placed']")
    lines = (mark.get_attribute("title") or "").splitlines()
    assert next(x for x in lines if "Old wreck" in x).endswith("obstacle Old wreck placed"), lines
    assert "Old wreck removed" in page.locator("#timeline-changes").inner_html()
    for _ in range(len(lines)):
        mark.click()
        if page.evaluate(wrecks) == 1:
            break
    assert page.evaluate("() => fleetConsole.replay.cursor") == drawn
    page.evaluate("t => fleetConsole.replay.seek(t)", drawn + 750)
    page.wait_for_function(f"() => ({wrecks})() === 1")
    shots(page, "replay-wreck-then")
    page.evaluate("t => fleetConsole.replay.seek(t)", drawn - 1000)
    page.wait_for_function(f"() => ({wrecks})() === 0")
    page.evaluate("() => fleetConsole.replay.seek(fleetConsole.replay.end)")
    page.wait_for_function(f"() => ({wrecks})() === 0")
    page.click("#replay-exit")
    expect(page.locator("#map path.obstacle")).to_have_count(0)


def test_zones_and_obstacles_drawn_or_removed_are_told(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A no-go zone drawn over the boats' water appeared on the map with no word."""
    page, _ = open_console()
    console.log_in(page, "mia")
    here = console.position(world, "demo-usv-2")
    near = LocalFrame(here["lat"], here["lon"])
    ring = [near.to_latlon(east, north) for east, north in ((300, 0), (340, 0), (340, 40))]
    polygon = console.polygon(ring)
    said = page.locator("#toasts .toast .msg")
    made = world.fleet.call(
        "POST", "/api/zones", json={"name": "Kelp bed", "kind": "no_go", "polygon": polygon}
    )
    expect(said.filter(has_text="no-go zone Kelp bed drawn on the map")).to_have_count(1)
    shots(page, "zone-drawn-told")
    world.fleet.call("PATCH", f"/api/zones/{made['zone_id']}", json={"name": "Kelp forest"})
    expect(said.filter(has_text="no-go zone Kelp forest changed")).to_have_count(1)
    world.fleet.call("DELETE", f"/api/zones/{made['zone_id']}")
    expect(said.filter(has_text="no-go zone Kelp forest removed")).to_have_count(1)
    buoy = world.fleet.call("POST", "/api/obstacles", json={"name": "Buoy", "polygon": polygon})
    expect(said.filter(has_text="obstacle Buoy drawn on the map")).to_have_count(1)
    world.fleet.call("DELETE", f"/api/obstacles/{buoy['obstacle_id']}")
    expect(said.filter(has_text="obstacle Buoy removed")).to_have_count(1)


def test_a_failsafe_and_a_late_presence_read_as_words(world: World, open_console: Any) -> None:
    """What happened read "failsafe entered remote → failsafe" and "failsafe left failsafe →
    remote"; an offline found after the server was down read as if it had just happened;
    a lease that ran out read "control expired for ben: expired"."""
    page, _ = open_console()
    console.log_in(page, "mia")
    said = page.evaluate(
        """async () => {
             const { describeEvent } = await import('./js/describe.js');
             const at = '2026-11-28T00:52:40.000Z';
             return [
               describeEvent({ kind: 'failsafe_entered', at,
                               data: { was: 'remote', control_mode: 'failsafe' } }),
               describeEvent({ kind: 'failsafe_left', at,
                               data: { was: 'failsafe', control_mode: 'remote' } }),
               describeEvent({ kind: 'presence', at,
                 data: { presence: 'offline', last_seen: '2026-11-28T00:51:33.000Z' } }),
               describeEvent({ kind: 'presence', at,
                 data: { presence: 'offline', last_seen: '2026-11-28T00:52:30.000Z' } }),
               describeEvent({ kind: 'control_expired', at,
                               data: { holder: 'ben', reason: 'expired' } }),
               describeEvent({ kind: 'control_expired', at, data: { holder: 'ben',
                 reason: 'operator_silent', operator_seen_at: '2026-11-28T00:51:33.000Z' } }),
             ];
           }"""
    )
    heard = page.evaluate(
        "() => new Date('2026-11-28T00:51:33.000Z').toLocaleTimeString([], {hour12: false})"
    )
    assert said == [
        "(it was under remote control)",
        "(now under remote control)",
        f"offline (last heard {heard})",
        "offline",  # heard 10 s before: found in time, nothing to add
        "ben: its time ran out",  # "control expired for ben: expired" said it twice
        f"ben: operator silent, none of their consoles heard since {heard}",
    ], said


def test_a_zone_drawn_across_a_mission_under_way_is_said(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A no-go zone drawn across a go_to under way was told as "drawn on the map" only;
    the boat sailed on into it (the server checks again only what is not yet delivered)."""
    instance = world.instances["demo-usv-2"]
    here = world.fleet.position(instance)
    frame = LocalFrame(here["lat"], here["lon"])
    page, _ = open_console()
    console.log_in(page, "ana")  # she holds Bravo (the world's grants)
    lat, lon = frame.to_latlon(0, 400)
    cid = world.fleet.submit(world.tokens["ana"], instance, "go_to", {"lat": lat, "lon": lon})
    zone_id = None
    try:
        expect(console.marker(page, "demo-usv-2").locator(".chip")).to_contain_text("go to")
        band = [frame.to_latlon(e, n) for e, n in ((-60, 150), (60, 150), (60, 200), (-60, 200))]
        body = {
            "name": "Kelp band",
            "kind": "no_go",
            "polygon": console.polygon(band),
        }
        zone_id = world.fleet.call("POST", "/api/zones", json=body)["zone_id"]
        said = page.locator("#toasts .toast .msg").filter(
            has_text="H2OmniX Bravo's go to under way now runs into no-go zone Kelp band"
        )
        expect(said).to_have_count(1)
        expect(said).to_contain_text("stop it, or send it another way")
        shots(page, "mission-crossed")
        assert world.fleet.command(cid)["status"] in ("acked", "accepted", "executing")
    finally:
        world.fleet.submit(world.tokens["ana"], instance, "stop", {})
        if zone_id:
            world.fleet.call("DELETE", f"/api/zones/{zone_id}")
