"""What a field manager's test of the console found, in a real browser (as
test_console_watch): the replay's window shown in AM/PM by an English browser, raw command
ids in "superseded by ...", no word of who holds control of the selected boat on a
phone's map, and exports that named each track by the vehicle's id alone. A world of its
own (the module's): ana holds every vehicle; the last test adds a vehicle."""

from __future__ import annotations

import json
import re
import xml.etree.ElementTree as ET
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo

import pytest
from playwright.sync_api import expect

from tests.web.conftest import PASSWORD, Shots, World
from tests.web.console_helpers import command_item, log_in, marker, replay_up

pytestmark = [pytest.mark.slow, pytest.mark.browser]

STAMP = "%Y-%m-%d %H:%M:%S"


def type_into(page: Any, field: Any, text: str) -> None:
    """What a person does: into the field, everything in it selected, typed over."""
    field.focus()
    page.keyboard.press("ControlOrMeta+A")
    page.keyboard.type(text)


def test_the_replay_window_is_typed_and_read_in_24_hour_local_time(
    world: World, open_console: Any, shots: Shots
) -> None:
    """An English browser showed the window's pickers as "02:05:00 PM". The window reads
    and is typed as "2026-11-26 14:05:00" in the browser's local time, said beside it,
    from the keyboard (Up and Down step the part under the caret); anything else is
    refused in words."""
    zone = ZoneInfo("America/New_York")
    page, _ = open_console(locale="en-US", timezone_id="America/New_York")
    log_in(page, "ana")
    replay_up(page)
    page.click('[data-tab="replay"]')
    frm, to = page.locator("#replay-from"), page.locator("#replay-to")
    expect(page.locator("#replay-zone")).to_contain_text(
        re.compile(r"24-hour, local time UTC-0[45]:00 \(America/New_York\)")
    )
    # the window offered (the last 15 min) reads in that form
    expect(frm).to_have_value(re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d$"))
    expect(to).to_have_value(re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d$"))

    now = datetime.now(zone).replace(microsecond=0)
    start, end = now - timedelta(minutes=3), now + timedelta(minutes=2)
    type_into(page, frm, start.strftime(STAMP))
    page.keyboard.press("Tab")  # on to "to"
    expect(to).to_be_focused()
    page.keyboard.press("ControlOrMeta+A")
    page.keyboard.type(end.strftime("%Y-%m-%d %H:%M"))  # the seconds left out
    page.keyboard.press("Tab")
    expect(frm).to_have_value(start.strftime(STAMP))
    expect(to).to_have_value(end.strftime("%Y-%m-%d %H:%M:00"))  # written back whole
    shots(page, "typed-24-hour")

    # Up and Down: the minutes (the caret in them) one more, one less
    frm.focus()
    frm.evaluate("el => el.setSelectionRange(15, 15)")
    page.keyboard.press("ArrowUp")
    expect(frm).to_have_value((start + timedelta(minutes=1)).strftime(STAMP))
    page.keyboard.press("ArrowDown")
    expect(frm).to_have_value(start.strftime(STAMP))

    # the window replayed is the one typed, in the browser's zone
    page.keyboard.press("Enter")  # submits the form, as Replay does
    expect(page.locator("#replay-bar")).to_be_visible()
    got = page.evaluate("[fleetConsole.replay.start, fleetConsole.replay.end]")
    assert got == [start.timestamp() * 1000, end.replace(second=0).timestamp() * 1000]
    expect(page.locator("#replay-time")).to_have_text(
        re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d \S+$")  # 24-hour, its zone after it
    )
    expect(page.locator("#replay-time")).not_to_contain_text(re.compile("AM|PM"))
    page.click("#replay-exit")

    # what is not such a time is refused in words, and nothing is read
    info = page.locator("#replay-info")
    for typed, said in (
        ("11/26/2026 2:05 PM", "is not a time this form reads: write it as 2026-11-26 14:05:00"),
        ("2026-02-30 10:00:00", "that month has days 1 to 28"),
        ("2026-03-08 02:30:00", "there is no such time here (the clocks went forward then)"),
    ):
        type_into(page, frm, typed)
        page.click("#replay-load")
        expect(info).to_contain_text(f"from: “{typed}”")
        expect(info).to_contain_text(said)
        expect(info).to_contain_text("nothing read")
        expect(frm).to_have_attribute("aria-invalid", "true")
    shots(page, "refused-time")


def test_back_to_live_returns_to_the_live_view_the_replay_left(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A replay fits the map to its tracks; Back to live left the map there, zoomed in on
    the replay's window. It returns to the view the manager had before the replay."""
    page, _ = open_console()
    log_in(page, "ana")
    replay_up(page)
    marker(page, "demo-usv-1").wait_for()
    view = "() => { const m = fleetConsole.map.map, c = m.getCenter(); "
    view += "return [c.lat, c.lng, m.getZoom()]; }"
    page.evaluate("fleetConsole.map.map.setView([43.5, 15.9], 9, {animate: false})")
    before = page.evaluate(view)
    page.click('[data-tab="replay"]')
    page.click('#replay-form [data-minutes="5"]')
    page.click("#replay-load")
    expect(page.locator("#replay-bar")).to_be_visible()
    assert page.evaluate(view)[2] > 12, "the replay fits the map to its tracks"
    page.click("#replay-exit")
    expect(page.locator("#replay-bar")).to_be_hidden()
    lat, lon, zoom = page.evaluate(view)
    assert zoom == before[2] and abs(lat - before[0]) < 1e-6 and abs(lon - before[1]) < 1e-6
    shots(page, "back-to-live-view")


def test_a_superseded_command_names_the_newer_one_not_its_id(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A command the boat replaced by a newer one read "superseded by keep_station
    c-5f0e…": the newer command is named by its type, who sent it and when, as the
    command list says it; its id only in a title."""
    vehicle = "demo-usv-1"
    page, _ = open_console(timezone_id="UTC")
    log_in(page, "ana")
    replay_up(page)
    marker(page, vehicle).click()
    page.click('[data-tab="vehicle"]')
    older = world.fleet.submit(world.tokens["ana"], world.instances[vehicle], "keep_station", {})
    expect(command_item(page, older)).to_have_attribute("data-stage", "executing")
    newer = world.fleet.submit(world.tokens["ana"], world.instances[vehicle], "keep_station", {})
    expect(command_item(page, older)).to_have_attribute("data-stage", "superseded")
    # the newer one's own line says when it was sent and by whom: the older one names it so
    sent = command_item(page, newer).locator("small")
    expect(sent).to_contain_text(re.compile(r"^\d\d:\d\d:\d\d by ana"))
    at = sent.inner_text()[:8]
    said = f"superseded by the keep station ana sent at {at}"
    expect(command_item(page, older)).to_contain_text(said)
    expect(command_item(page, older).locator(".superseded-by")).to_have_attribute(
        "title", f"command {newer}"
    )
    # and so does the line of its end among the recent events
    ended = page.locator("#vehicle-pane ol.events li", has_text="keep station superseded")
    expect(ended).to_contain_text(f"(by the keep station ana sent at {at})")
    expect(ended).to_have_attribute("title", f"superseded by command {newer}")
    expect(page.locator("#vehicle-pane")).not_to_contain_text(newer)
    shots(page, "superseded-named")

    # the replay's list of what happened names it by the events it read (the window's end
    # typed a minute on: one set to now ends at the last whole second, maybe before them)
    page.click('[data-tab="replay"]')
    page.click('#replay-form [data-minutes="5"]')
    later = datetime.now(ZoneInfo("UTC")) + timedelta(minutes=1)
    type_into(page, page.locator("#replay-to"), later.strftime(STAMP))
    for vehicle_id in ("demo-usv-1", "demo-usv-2", "demo-usv-3"):
        page.locator(f'#replay-vehicles input[value="{vehicle_id}"]').set_checked(
            vehicle_id == vehicle
        )
    page.click("#replay-load")
    expect(page.locator("#replay-bar")).to_be_visible()
    line = page.locator("#replay-events li", has_text="keep station superseded")
    expect(line).to_contain_text(re.compile(r"\(by the keep station ana sent at \d\d:\d\d:\d\d\)"))
    expect(line).to_have_attribute("title", f"superseded by command {newer}")
    expect(page.locator("#replay-events")).not_to_contain_text(newer)
    shots(page, "superseded-in-replay")
    page.click("#replay-exit")


def test_a_phone_s_map_says_who_holds_control_of_the_selected_boat(
    world: World, open_console: Any, shots: Shots
) -> None:
    """On a phone the map said nothing of who held control of the boat selected (the
    vehicle panel beside the map says it on a wider screen): it says it over the map, in
    the panel's words, as control changes, and names each boat when several are chosen."""
    vehicle, other = "demo-usv-2", "demo-usv-1"
    operator, _ = open_console(viewport=(390, 844))
    log_in(operator, "ana")  # she holds every boat (the world's grants)
    marker(operator, vehicle).click()
    said = operator.locator("#map-holder")
    expect(said).to_be_visible()
    expect(said).to_have_text(re.compile(r"^you hold control until \d\d:\d\d:\d\d \(in \d+ min\)$"))
    # the panel's words: what the Vehicle tab says of it begins so
    line = said.inner_text().split(" (")[0]
    operator.click('[data-tab="vehicle"]')
    expect(operator.locator("#vehicle-pane .control-line")).to_contain_text(line)
    operator.click('[data-tab="map"]')
    shots(operator, "phone-holder-mine")

    watcher, _ = open_console(viewport=(390, 844))
    log_in(watcher, "ben")
    marker(watcher, vehicle).click()
    said = watcher.locator("#map-holder")
    expect(said).to_have_text(
        re.compile(r"^ana holds control until \d\d:\d\d:\d\d \(in \d+ min\)$")
    )
    # clear of the map's buttons, and nothing scrolls sideways
    box = said.bounding_box()
    for button in (".leaflet-control-zoom", ".leaflet-control-layers", ".fit-all"):
        b = watcher.locator(button).bounding_box()
        assert (
            box["x"] + box["width"] <= b["x"]
            or b["x"] + b["width"] <= box["x"]
            or (box["y"] + box["height"] <= b["y"] or b["y"] + b["height"] <= box["y"])
        ), (button, box, b)
    assert watcher.evaluate("document.documentElement.scrollWidth") <= 390
    shots(watcher, "phone-holder-other")

    # control released: said at once, from the socket
    world.as_user(
        "ana", "POST", "/client/release_control", json={"instance_id": world.instances[vehicle]}
    )
    expect(said).to_have_text("nobody holds control")
    # several boats ticked: each line names its boat
    watcher.click('[data-tab="fleet"]')
    watcher.locator(f'input[aria-label="select {other}"]').check()
    watcher.click('[data-tab="map"]')
    expect(said.locator(".holder-line")).to_have_count(2)
    expect(said.locator(f'.holder-line[data-vehicle="{vehicle}"]')).to_have_text(
        "H2OmniX Bravo: nobody holds control"
    )
    expect(said.locator(f'.holder-line[data-vehicle="{other}"]')).to_contain_text(
        "H2OmniX Alpha: ana holds control until"
    )
    shots(watcher, "phone-holder-several")
    world.fleet.grant(world.instances[vehicle], "ana")  # as the world was

    # a wider screen has the panel beside the map: no line over it
    desktop, _ = open_console()
    log_in(desktop, "ben")
    marker(desktop, vehicle).click()
    expect(desktop.locator("#vehicle-pane .control-line")).to_contain_text("ana holds control")
    expect(desktop.locator("#map-holder")).to_be_hidden()


def test_an_export_names_its_file_and_tracks_by_the_vehicles(
    world: World, open_console: Any, shots: Shots
) -> None:
    """An export was "fleet-replay-2026-11-25T004351Z.gpx" with tracks named "demo-usv-1":
    the file is named by the vehicles' names (the id after one that another vehicle shares,
    whatever a name holds made safe for a file system) and each track by its vehicle's name
    and id. Two vehicles are added, without agents: one named as Alpha, one named with
    characters no file name may hold."""
    ns = {"g": "http://www.topografix.com/GPX/1/1"}
    added = {"demo-usv-9": "H2OmniX Alpha", "demo-usv-8": 'Tug "North/South": 2?'}
    for vehicle_id, name in added.items():
        body = {"vehicle_id": vehicle_id, "name": name, "vehicle_type": "usv"}
        world.fleet.call("POST", "/api/vehicles", json=body)
    sees = ["demo-usv-1", "demo-usv-2", *added]
    body = {"username": "fay", "role": "viewer", "vehicles": sees, "password": PASSWORD}
    world.fleet.call("POST", "/api/users", json=body)
    page, _ = open_console()
    log_in(page, "fay", markers=None)
    replay_up(page)
    page.click('[data-tab="replay"]')
    expect(page.locator("#replay-vehicles input")).to_have_count(4)

    def export(chosen: list[str], format: str) -> tuple[str, Any]:
        for vehicle_id in sees:
            page.locator(f'#replay-vehicles input[value="{vehicle_id}"]').set_checked(
                vehicle_id in chosen
            )
        page.click('#replay-form [data-minutes="5"]')
        page.click("#replay-load")
        expect(page.locator("#replay-bar")).to_be_visible()
        with page.expect_download() as got:
            page.click(f'#replay-export button[data-format="{format}"]')
        page.click("#replay-exit")
        return got.value.suggested_filename, got.value.path()

    name, path = export(["demo-usv-1", "demo-usv-8", "demo-usv-9"], "gpx")
    stamp = r"-\d{4}-\d\d-\d\dT\d{6}Z"
    assert re.fullmatch(
        r"fleet-replay-H2OmniX-Alpha-demo-usv-1_Tug-North-South-2_H2OmniX-Alpha-demo-usv-9"
        + stamp
        + r"\.gpx",
        name,
    ), name
    tracks = ET.parse(path).getroot().findall("g:trk", ns)
    assert [t.findtext("g:name", namespaces=ns) for t in tracks] == [
        "H2OmniX Alpha (demo-usv-1)",
        'Tug "North/South": 2? (demo-usv-8)',
        "H2OmniX Alpha (demo-usv-9)",
    ]
    name, path = export(["demo-usv-1", "demo-usv-9"], "geojson")
    assert re.fullmatch(
        r"fleet-replay-H2OmniX-Alpha-demo-usv-1_H2OmniX-Alpha-demo-usv-9" + stamp + r"\.geojson",
        name,
    ), name
    features = json.loads(Path(path).read_text())["features"]
    assert [f["properties"]["name"] for f in features] == [
        "H2OmniX Alpha (demo-usv-1)",
        "H2OmniX Alpha (demo-usv-9)",
    ]
    # a name no other vehicle has: the name alone
    name, _ = export(["demo-usv-2"], "gpx")
    assert re.fullmatch(r"fleet-replay-H2OmniX-Bravo" + stamp + r"\.gpx", name), name
    shots(page, "exported")
