"""The console (``/``) and ``/docs`` in headless chromium, against a real server with the
demo's three simulated vehicles: log in, watch them move, command one from the map, draw
a path round an obstacle, stop with a confirmation, grant control on a phone, replay a
window, lose the link and get it back, read the API docs. Screenshots: one per step, in
each test's output folder (and ``$FLEET_WEB_SHOTS``); ``FLEET_README_SHOT=1`` also
writes the README's picture, ``docs/img/dashboard.png``.

The tests run in file order on one server (each builds on what the fleet did before).
"""

from __future__ import annotations

import json
import math
import os
import re
import xml.etree.ElementTree as ET
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo

import pytest
from playwright.sync_api import expect

from tests.agent.procs import wait_until
from tests.web.conftest import PASSWORD, Shots, World, no_requests
from vehicle_client.geo import LocalFrame, distance_m

pytestmark = [pytest.mark.slow, pytest.mark.browser]

ROOT = Path(__file__).resolve().parents[2]
README_SHOT = ROOT / "docs" / "img" / "dashboard.png"
ALL = ("demo-usv-1", "demo-usv-2", "demo-usv-3")


# ---- helpers ------------------------------------------------------------------------


def log_in(page: Any, username: str) -> None:
    page.goto("/")
    page.fill("#login-user", username)
    page.fill("#login-password", PASSWORD)
    page.click("#login-form button[type=submit]")
    expect(page.locator("#link")).to_have_attribute("data-state", "live")
    expect(page.locator(".vicon[data-vehicle]")).to_have_count(3)


def marker(page: Any, vehicle_id: str) -> Any:
    return page.locator(f'.vicon:not(.replay)[data-vehicle="{vehicle_id}"]')


def marker_latlon(page: Any, vehicle_id: str) -> tuple[float, float]:
    m = marker(page, vehicle_id)
    return float(m.get_attribute("data-lat")), float(m.get_attribute("data-lon"))


def screen_point(page: Any, lat: float, lon: float) -> tuple[float, float]:
    """Where (lat, lon) is on the page, in CSS pixels."""
    x, y = page.evaluate(
        """([lat, lon]) => {
            const p = fleetConsole.map.map.latLngToContainerPoint([lat, lon]);
            const r = document.getElementById("map").getBoundingClientRect();
            return [r.left + p.x, r.top + p.y];
        }""",
        [lat, lon],
    )
    return x, y


def next_frames(page: Any) -> None:
    """Until the page has drawn twice (the labels are placed in an animation frame)."""
    page.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")


def centre_on(page: Any, lat: float, lon: float, zoom: float) -> None:
    """Pan and zoom the map as a user would before clicking there."""
    page.evaluate(
        "([lat, lon, z]) => fleetConsole.map.map.setView([lat, lon], z, {animate: false})",
        [lat, lon, zoom],
    )
    next_frames(page)


def position(world: World, vehicle_id: str) -> dict[str, Any]:
    return world.fleet.position(world.instances[vehicle_id])


def command_item(page: Any, command_id: str) -> Any:
    return page.locator(f'#vehicle-pane li[data-command="{command_id}"]')


def newest_command(world: World, vehicle_id: str, kind: str) -> dict[str, Any] | None:
    """The vehicle's newest command of that type (None: none yet)."""
    page = world.fleet.call(
        "GET", "/client/get_fbmessage", params={"instance_id": world.instances[vehicle_id]}
    )
    return next((c for c in page["commands"] if c["type"] == kind), None)


def boxes_overlap(a: dict[str, float], b: dict[str, float]) -> bool:
    return (
        a["x"] < b["x"] + b["width"]
        and b["x"] < a["x"] + a["width"]
        and a["y"] < b["y"] + b["height"]
        and b["y"] < a["y"] + a["height"]
    )


def label_boxes(page: Any) -> list[dict[str, float]]:
    return [
        page.locator(f'.vicon:not(.replay)[data-vehicle="{v}"] .vlabel').bounding_box() for v in ALL
    ]


def assert_labels_apart(page: Any) -> None:
    boxes = label_boxes(page)
    for i, a in enumerate(boxes):
        for b in boxes[i + 1 :]:
            assert not boxes_overlap(a, b), f"labels overlap: {a} {b}"


def stored_sample(
    world: World, vehicle_id: str, latlon: tuple[float, float]
) -> dict[str, Any] | None:
    """The stored sample of the last minute at exactly that position (None: not stored yet)."""
    since = datetime.now(UTC).timestamp() * 1000 - 60_000
    points = world.fleet.call(
        "GET", f"/api/vehicles/{vehicle_id}/track", params={"from": iso(since)}
    )["points"]
    return next((p for p in points if (p["lat"], p["lon"]) == latlon), None)


def ms(ts: str) -> float:
    return datetime.fromisoformat(ts.replace("Z", "+00:00")).timestamp() * 1000


# ---- the tests ------------------------------------------------------------------------


def test_log_in_and_watch_the_fleet_move_live(
    world: World, open_console: Any, shots: Shots
) -> None:
    # demo-usv-3 goes round a square, demo-usv-2 a little east: something to watch
    p3 = position(world, "demo-usv-3")
    frame3 = LocalFrame(p3["lat"], p3["lon"])
    square = [frame3.to_latlon(e, n) for e, n in ((30, 0), (30, 30), (0, 30), (0, 0))] * 3
    world.fleet.submit(
        world.tokens["ana"], world.instances["demo-usv-3"], "follow_path",
        {"waypoints": [{"lat": a, "lon": o} for a, o in square]},
    )  # fmt: skip
    p2 = position(world, "demo-usv-2")
    east = LocalFrame(p2["lat"], p2["lon"]).to_latlon(35, 5)
    world.fleet.submit(
        world.tokens["ana"], world.instances["demo-usv-2"], "go_to",
        {"lat": east[0], "lon": east[1]},
    )  # fmt: skip

    page, guard = open_console()
    page.goto("/")
    expect(page.locator("#login-form")).to_be_visible()
    shots(page, "login")
    # a token pasted that the server refuses: the login page says so
    page.click("#login details summary")
    page.fill("#login-token", "fct_not-a-token-anybody-has")
    page.click("#login-token-go")
    expect(page.locator("#login-error")).to_have_text(
        "this token was refused: it is wrong, revoked or expired"
    )
    log_in(page, "ana")
    expect(page.locator("#who")).to_have_text("ana · operator")
    for vehicle_id in ALL:
        expect(marker(page, vehicle_id)).to_have_attribute("data-presence", "online")
    shots(page, "fleet-live")

    # positions move on the map from the socket alone: no HTTP call meanwhile
    with no_requests(guard):
        before = marker_latlon(page, "demo-usv-3")
        page.wait_for_function(
            """([id, lat, lon]) => {
                const el = document.querySelector(`.vicon[data-vehicle="${id}"]`);
                return el && (+el.dataset.lat !== lat || +el.dataset.lon !== lon);
            }""",
            arg=["demo-usv-3", *before],
        )
        after = marker_latlon(page, "demo-usv-3")
        assert distance_m(*before, *after) > 0.2
        stored = position(world, "demo-usv-3")
        assert distance_m(*after, stored["lat"], stored["lon"]) < 15  # the same vehicle, live
        # the arrow points along the heading of the sample that put the marker there
        turned = marker(page, "demo-usv-3").locator("path").get_attribute("transform")
        shown = float(re.fullmatch(r"rotate\((.+)\)", turned or "")[1])
        sample = wait_until(lambda: stored_sample(world, "demo-usv-3", after), "that sample")
        assert shown == sample["heading_deg"]
        page.wait_for_function(  # a trail grows, sample by sample
            "fleetConsole.fleet.vehicles.get('demo-usv-3').trail.length >= 4"
        )
    assert_labels_apart(page)
    shots(page, "moving")

    # zoomed far out, the three markers crowd together: the labels still keep apart
    p1 = position(world, "demo-usv-1")
    centre_on(page, p1["lat"], p1["lon"], 14)
    assert_labels_apart(page)
    shots(page, "labels-zoomed-out")


def test_select_a_vehicle_and_send_go_to_by_clicking_the_map(
    world: World, open_console: Any, shots: Shots
) -> None:
    page, guard = open_console()
    log_in(page, "ana")
    start = position(world, "demo-usv-1")
    centre_on(page, start["lat"], start["lon"], 19)
    marker(page, "demo-usv-1").click()
    expect(marker(page, "demo-usv-1")).to_have_class(re.compile(r"\bselected\b"))
    expect(page.locator("#actions")).to_be_visible()
    expect(page.locator("#vehicle-pane h2")).to_contain_text("H2OmniX Alpha")
    shots(page, "selected")

    target = LocalFrame(start["lat"], start["lon"]).to_latlon(6.0, 10.0)  # 10 m north, 6 m east
    page.click('[data-tool="go_to"]')
    expect(page.locator("#tool-hint")).to_be_visible()
    x, y = screen_point(page, *target)
    page.mouse.click(x, y)
    sent = wait_until(lambda: newest_command(world, "demo-usv-1", "go_to"), "the go_to stored")
    assert distance_m(sent["args"]["lat"], sent["args"]["lon"], *target) < 0.5  # where clicked
    assert sent["issued_by"] == "ana"
    item = command_item(page, sent["command_id"])
    expect(item).to_be_visible()
    shots(page, "go-to-sent")

    # its life shows beside the vehicle and in the panel: delivered, acked, ..., done
    expect(item).to_have_attribute("data-stage", "done", timeout=60_000)
    steps = item.locator(".steps").inner_text()
    assert steps.split(" → ")[:2] == ["queued", "delivered"], steps
    assert steps.endswith("done") and "acked" in steps, steps
    expect(marker(page, "demo-usv-1").locator(".chip")).to_have_text("go_to · done")
    assert world.fleet.command(sent["command_id"])["status"] == "done"
    shots(page, "go-to-done")

    # keep station where the map is clicked, 4 m south of where it arrived
    here = position(world, "demo-usv-1")
    station = LocalFrame(here["lat"], here["lon"]).to_latlon(0.0, -4.0)
    page.fill("#opt-radius", "3")
    page.click('[data-tool="station"]')
    page.mouse.click(*screen_point(page, *station))
    held = wait_until(lambda: newest_command(world, "demo-usv-1", "keep_station"), "station")
    assert distance_m(held["args"]["lat"], held["args"]["lon"], *station) < 0.5
    assert held["args"]["radius_m"] == 3
    expect(command_item(page, held["command_id"])).to_have_attribute(
        "data-stage", "executing", timeout=30_000
    )
    expect(page.locator("path.leaflet-interactive[stroke-dasharray='3 4']")).to_have_count(1)
    shots(page, "station-here")

    # two selected (the fleet table's boxes): one Hold here reaches both
    page.click('[data-tab="fleet"]')
    page.locator('#fleet-table tr[data-vehicle="demo-usv-2"] input[type=checkbox]').check()
    expect(page.locator("#selection")).to_have_text("2 selected: H2OmniX Alpha, H2OmniX Bravo")
    expect(marker(page, "demo-usv-2")).to_have_class(re.compile(r"\bselected\b"))
    before = held["command_id"]
    # a radius or a speed out of its field's range is said, and nothing is sent (a
    # radius of 0 went out as 5 m)
    with no_requests(guard):
        page.fill("#opt-radius", "0")
        page.click("#hold")
        expect(page.locator("#toasts")).to_contain_text("station radius is 1 to 500 m")
        page.fill("#opt-speed", "25")
        page.click('[data-tool="go_to"]')
        page.mouse.click(*screen_point(page, *station))
        expect(page.locator("#toasts")).to_contain_text("speed is 0.1 to 20 m/s")
        page.keyboard.press("Escape")  # the tool put away
        expect(page.locator("#tool-hint")).to_be_hidden()
        page.fill("#opt-speed", "")
        next_frames(page)
    page.fill("#opt-radius", "3")
    page.click("#hold")
    for vehicle_id in ("demo-usv-1", "demo-usv-2"):

        def hold(v: str = vehicle_id) -> dict[str, Any] | None:
            c = newest_command(world, v, "keep_station")
            return c if c and c["command_id"] != before and "lat" not in c["args"] else None

        assert wait_until(hold, f"Hold here for {vehicle_id}")["args"] == {"radius_m": 3}
    shots(page, "hold-two")


def test_draw_a_path_planned_round_an_obstacle(
    world: World, open_console: Any, shots: Shots
) -> None:
    here = position(world, "demo-usv-2")
    frame = LocalFrame(here["lat"], here["lon"])
    corners = [frame.to_latlon(e, n) for e, n in ((-6, 14), (6, 14), (6, 24), (-6, 24), (-6, 14))]
    world.fleet.call(
        "POST", "/api/obstacles",
        json={"name": "pontoon", "clearance_m": 3,
              "polygon": {"type": "Polygon", "coordinates": [[[o, a] for a, o in corners]]}},
    )  # fmt: skip
    corners = ((-10, -90), (10, -90), (10, -70), (-10, -70), (-10, -90))  # 80 m south
    shoal = [[o, a] for a, o in (frame.to_latlon(e, n) for e, n in corners)]
    polygon = {"type": "Polygon", "coordinates": [shoal]}
    body = {"name": "shoal", "kind": "no_go", "polygon": polygon}
    world.fleet.call("POST", "/api/zones", json=body)
    page, _ = open_console()
    log_in(page, "ana")
    expect(page.locator("path.obstacle")).to_have_count(1)
    expect(page.locator("path.zone-no_go")).to_have_count(1)
    centre_on(page, *frame.to_latlon(0, 20), 19)
    marker(page, "demo-usv-2").click()
    page.click('[data-tool="path"]')
    expect(page.locator("#path-bar")).to_be_visible()
    waypoints = [frame.to_latlon(0, 38), frame.to_latlon(10, 42)]
    for lat, lon in waypoints:
        page.mouse.click(*screen_point(page, lat, lon))
    expect(page.locator("#path-count")).to_have_text("2 waypoints")
    expect(page.locator(".waypoint")).to_have_count(2)
    assert page.locator("#path-plan").is_checked()
    shots(page, "path-drawn")
    page.click("#path-send")

    sent = wait_until(lambda: newest_command(world, "demo-usv-2", "follow_path"), "the path")
    clicked = sent["args"]["waypoints"]
    for got, want in zip(clicked, waypoints, strict=True):
        assert distance_m(got["lat"], got["lon"], *want) < 0.5
    planned = sent["args"]["path"]  # the server planned it: round the pontoon
    assert len(planned) > len(clicked)
    item = command_item(page, sent["command_id"])
    expect(item).to_be_visible()
    expect(item).to_have_attribute("data-stage", "executing", timeout=30_000)
    expect(page.locator("path.planned.path-of-demo-usv-2")).to_be_visible()
    shots(page, "path-executing")

    if os.environ.get("FLEET_README_SHOT") == "1":
        page.evaluate("fleetConsole.map.fitFleet()")
        for close in page.locator("#toasts .close").all():
            close.click()
        next_frames(page)
        README_SHOT.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(README_SHOT))
    shots(page, "dashboard")


def test_stop_needs_its_confirmation(world: World, open_console: Any, shots: Shots) -> None:
    page, guard = open_console()
    log_in(page, "ana")
    before = {c["command_id"] for c in world.fleet.call(
        "GET", "/client/get_fbmessage", params={"instance_id": world.instances["demo-usv-3"]}
    )["commands"]}  # fmt: skip
    marker(page, "demo-usv-3").click()
    page.click("#stop-selected")
    dialog = page.locator("#confirm")
    expect(dialog).to_be_visible()
    ok = page.locator("#confirm-ok")
    expect(ok).to_be_disabled()  # a second tap on Stop lands on nothing
    expect(page.locator("#confirm-cancel")).to_be_focused()  # Enter cancels
    shots(page, "stop-confirm")
    page.keyboard.press("Enter")
    expect(dialog).to_be_hidden()
    page.click("#stop-selected")
    expect(ok).to_be_enabled()
    page.keyboard.press("Escape")
    expect(dialog).to_be_hidden()
    next_frames(page)
    assert not [r for r in guard.requests if "/client/submit_control" in r], "sent unconfirmed"
    after = world.fleet.call(
        "GET", "/client/get_fbmessage", params={"instance_id": world.instances["demo-usv-3"]}
    )["commands"]
    assert [c for c in after if c["command_id"] not in before] == [], "sent without confirming"

    page.click('#actions button[data-tool="go_to"]')  # a tool armed when Stop is pressed
    page.click("#stop-selected")
    expect(ok).to_be_enabled()
    ok.click()
    # the stop disarms it: a look at the map afterwards does not send the vehicle off again
    expect(page.locator("#actions button[data-tool].active")).to_have_count(0)
    expect(page.locator("#tool-hint")).to_be_hidden()
    stop = wait_until(lambda: newest_command(world, "demo-usv-3", "stop"), "the stop stored")
    assert stop["command_id"] not in before
    item = command_item(page, stop["command_id"])
    expect(item).to_have_attribute("data-stage", "done", timeout=30_000)
    shots(page, "stopped")

    # Stop all: its own confirmation, then a stop for every vehicle
    page.click("#stop-all")
    expect(page.locator("#confirm-title")).to_have_text("Stop every vehicle?")
    expect(ok).to_be_disabled()
    shots(page, "stop-all-confirm")
    expect(ok).to_be_enabled()
    ok.click()
    for vehicle_id in ALL:

        def new_stop(v: str = vehicle_id) -> dict[str, Any] | None:
            c = newest_command(world, v, "stop")
            return c if c and c["command_id"] != stop["command_id"] else None

        stopped = wait_until(new_stop, f"a stop for {vehicle_id}")
        assert stopped["issued_by"] == "ana"
        expect(marker(page, vehicle_id).locator(".chip")).to_contain_text("stop ·")
    shots(page, "stopped-all")


def test_replay_puts_each_marker_where_the_store_has_it(
    world: World, open_console: Any, shots: Shots
) -> None:
    page, _ = open_console()
    log_in(page, "ana")
    page.click('[data-tab="replay"]')
    # nothing selected: every vehicle is offered ticked, however the fleet arrived
    expect(page.locator("#replay-vehicles input:checked")).to_have_count(len(ALL))
    page.click('button[data-minutes="5"]')
    for vehicle_id in ALL:
        page.locator(f'#replay-vehicles input[value="{vehicle_id}"]').set_checked(
            vehicle_id != "demo-usv-1"
        )
    page.click("#replay-load")
    expect(page.locator("#replay-bar")).to_be_visible()
    expect(page.locator(".vicon.replay")).to_have_count(2)

    # said on the map and beside the link's state: never read as live
    def after(selector: str) -> str:
        return str(page.locator(selector).evaluate("el => getComputedStyle(el, '::after').content"))

    assert after("#map-pane") == '"REPLAY: recorded positions, not live"'
    assert after("#link") == '" · map: replay"'
    start, end = page.evaluate("[fleetConsole.replay.start, fleetConsole.replay.end]")
    stored = {
        v: world.fleet.call(
            "GET",
            f"/api/vehicles/{v}/track",
            params={"from": iso(start), "to": iso(end)},
        )["points"]
        for v in ("demo-usv-2", "demo-usv-3")
    }
    assert all(len(points) >= 5 for points in stored.values())
    shots(page, "replay-loaded")

    slider = page.locator("#replay-slider")
    first = min(ms(p["ts"]) for points in stored.values() for p in points)
    last = max(ms(p["ts"]) for points in stored.values() for p in points)
    for fraction in (0.35, 0.7, 1.0):  # of the time the vehicles were recorded
        slider.fill(str(int(first + (last - first) * fraction - start)))
        cursor = page.evaluate("fleetConsole.replay.cursor")
        for vehicle_id, points in stored.items():
            want = expected_at(points, cursor)
            got = page.locator(f'.vicon.replay[data-vehicle="{vehicle_id}"]')
            lat, lon = float(got.get_attribute("data-lat")), float(got.get_attribute("data-lon"))
            assert distance_m(lat, lon, *want) < 0.01, (vehicle_id, cursor, (lat, lon), want)
            # and drawn there: the marker's centre is the map's point for that position
            box = got.bounding_box()
            x, y = screen_point(page, *want)
            assert abs(box["x"] + box["width"] / 2 - x) < 1.5
            assert abs(box["y"] + box["height"] / 2 - y) < 1.5
        shots(page, f"replay-at-{int(fraction * 100)}")

    # play from the start of the recording at 10x: the cursor moves, events light up
    slider.fill(str(int(first - start)))
    played_from = page.evaluate("fleetConsole.replay.cursor")
    page.select_option("#replay-speed", "10")
    page.click("#replay-play")
    expect(page.locator("#replay-events li.hit").first).to_be_visible(timeout=20_000)
    shots(page, "replay-playing")
    page.click("#replay-play")  # pause
    assert page.evaluate("fleetConsole.replay.playing") is False
    assert page.evaluate("fleetConsole.replay.cursor") > played_from
    passed = page.locator("#replay-events li.passed").count()
    assert passed >= 1
    kinds = set(
        page.eval_on_selector_all("#replay-events li", "els => els.map(e => e.dataset.kind)")
    )
    assert {"command", "control_grant"} <= kinds, kinds

    # export the window: one file, both vehicles, every stored point
    with page.expect_download() as got:
        page.click('#replay-export button[data-format="gpx"]')
    assert re.fullmatch(r"fleet-replay-\d{4}-\d\d-\d\dT\d{6}Z\.gpx", got.value.suggested_filename)
    gpx = ET.parse(got.value.path())
    ns = {"g": "http://www.topografix.com/GPX/1/1"}
    tracks = gpx.getroot().findall("g:trk", ns)
    assert sorted(t.findtext("g:name", namespaces=ns) for t in tracks) == [
        "demo-usv-2", "demo-usv-3",
    ]  # fmt: skip
    for t in tracks:
        name = t.findtext("g:name", namespaces=ns)
        assert len(t.findall(".//g:trkpt", ns)) == len(stored[name])
    with page.expect_download() as got:
        page.click('#replay-export button[data-format="geojson"]')
    collection = json.loads(Path(got.value.path()).read_text())
    assert collection["type"] == "FeatureCollection"
    assert [len(f["geometry"]["coordinates"]) for f in collection["features"]] == [
        len(stored[f["properties"]["vehicle_id"]]) for f in collection["features"]
    ]
    page.click("#replay-exit")
    expect(page.locator(".vicon.replay")).to_have_count(0)
    assert after("#map-pane") == "none" and after("#link") == "none"
    expect(marker(page, "demo-usv-1")).to_be_visible()


def test_a_lost_link_shows_and_comes_back(world: World, open_console: Any, shots: Shots) -> None:
    page, _ = open_console(timezone_id="Europe/Zagreb")  # a browser an hour east of UTC
    log_in(page, "ana")
    # Times are this browser's local times: the bar says which (UTC+1, or +2 in summer).
    hours = datetime.now(ZoneInfo("Europe/Zagreb")).utcoffset() // timedelta(hours=1)
    expect(page.locator("#tz")).to_have_text(f"times in UTC+0{hours}:00 (Europe/Zagreb)")
    badge = page.locator(".presence").first
    expect(badge).to_have_text("online")

    def marked(content: str) -> None:
        """Every presence badge ends with ``content`` (CSS: "?" while the link is lost)."""
        page.wait_for_function(
            """want => [...document.querySelectorAll('.presence')].every(
                 el => getComputedStyle(el, '::after').content === want)""",
            arg=content,
            timeout=10_000,
        )

    marked("none")
    world.server.stop(grace_s=5.0)
    expect(page.locator("#link")).to_have_attribute("data-state", "lost")
    expect(page.locator("#link")).to_contain_text("link lost")
    marked('"?"')  # presence as last heard, not vouched for
    shots(page, "link-lost")
    world.server.start()  # the same port and store; the agents find it again
    expect(page.locator("#link")).to_have_attribute("data-state", "live", timeout=30_000)
    expect(page.locator("#link")).to_have_text("live")
    # the vehicles come back online in the view, from the socket again
    for vehicle_id in ALL:
        expect(marker(page, vehicle_id)).to_have_attribute(
            "data-presence", "online", timeout=30_000
        )
    marked("none")
    shots(page, "link-back")


def test_a_network_gone_silent_is_a_lost_link_within_25_s(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A phone out of signal: the socket neither answers nor closes. The console's own
    check (15 s, then 10 s for the answer) says so; it used to stay "live", every boat
    green, until the network came back."""
    page, _ = open_console()
    log_in(page, "ana")
    page.context.set_offline(True)
    expect(page.locator("#link")).to_have_attribute("data-state", "lost", timeout=35_000)
    expect(page.locator("#link")).to_contain_text("link lost")
    shots(page, "silent-network-lost")
    page.context.set_offline(False)
    expect(page.locator("#link")).to_have_attribute("data-state", "live", timeout=30_000)


def test_swagger_ui_at_docs_works_offline(world: World, open_console: Any, shots: Shots) -> None:
    page, guard = open_console()
    page.goto("/docs")
    expect(page.locator(".swagger-ui .info .title")).to_contain_text("fleet-cloud")
    expect(page.locator(".opblock-summary-path", has_text="/client/submit_control")).to_be_visible()
    assert any("/vendor/swagger-ui/swagger-ui-bundle.js" in r for r in guard.requests)
    shots(page, "docs")


# ---- what the replay must show ----------------------------------------------------------


def iso(epoch_ms: float) -> str:
    return datetime.fromtimestamp(epoch_ms / 1000, UTC).isoformat(timespec="milliseconds")


def expected_at(points: list[dict[str, Any]], t: float) -> tuple[float, float]:
    """The stored position at ``t``: the sample at or before it, or on the straight line to
    the next one when they are at most 30 s apart (what the console's replay promises)."""
    before = [p for p in points if ms(p["ts"]) <= t]
    assert before, "the cursor is before the first sample"
    a = before[-1]
    later = [p for p in points if ms(p["ts"]) > t]
    if not later or ms(a["ts"]) == t or ms(later[0]["ts"]) - ms(a["ts"]) > 30_000:
        return a["lat"], a["lon"]
    b = later[0]
    f = (t - ms(a["ts"])) / (ms(b["ts"]) - ms(a["ts"]))
    return a["lat"] + (b["lat"] - a["lat"]) * f, a["lon"] + (b["lon"] - a["lon"]) * f


def test_expected_at_is_the_stored_sample_on_its_time() -> None:
    points = [
        {"ts": "2026-01-01T00:00:00.000Z", "lat": 1.0, "lon": 2.0},
        {"ts": "2026-01-01T00:00:10.000Z", "lat": 2.0, "lon": 4.0},
    ]
    t0 = ms(points[0]["ts"])
    assert expected_at(points, t0) == (1.0, 2.0)
    assert expected_at(points, t0 + 5000) == (1.5, 3.0)
    assert expected_at(points, t0 + 20_000) == (2.0, 4.0)
    assert math.isclose(expected_at(points, t0 + 10_000)[0], 2.0)
