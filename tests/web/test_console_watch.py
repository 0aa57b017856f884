"""Watching the fleet in the console (``/``), in headless chromium against a real server with
the demo's three simulated vehicles: log in and watch them move from the socket alone,
replay a window with each marker where the store has it (and export it), lose the link
and get it back, a network gone silent, and ``/docs`` offline. Screenshots: one per
step, in each test's output folder (and ``$FLEET_WEB_SHOTS``).

The tests run in file order on one server: the replay plays back what the first test set
moving, and the lost link stops and starts the server.
"""

from __future__ import annotations

import json
import math
import re
import xml.etree.ElementTree as ET
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo

import pytest
from playwright.sync_api import expect

from tests.agent.procs import wait_until
from tests.web import console_helpers as console
from tests.web.conftest import Shots, World, no_requests
from vehicle_client.geo import LocalFrame, distance_m

pytestmark = [pytest.mark.slow, pytest.mark.browser]


def marker_latlon(page: Any, vehicle_id: str) -> tuple[float, float]:
    m = console.marker(page, vehicle_id)
    return float(m.get_attribute("data-lat")), float(m.get_attribute("data-lon"))


def stored_sample(
    world: World, vehicle_id: str, latlon: tuple[float, float]
) -> dict[str, Any] | None:
    """The stored sample of the last minute at exactly that position (None: not stored yet)."""
    since = datetime.now(UTC).timestamp() * 1000 - 60_000
    points = world.fleet.call(
        "GET", f"/api/vehicles/{vehicle_id}/track", params={"from": iso(since)}
    )["points"]
    return next((p for p in points if (p["lat"], p["lon"]) == latlon), None)


def test_log_in_and_watch_the_fleet_move_live(
    world: World, open_console: Any, shots: Shots
) -> None:
    # demo-usv-3 goes round a square, demo-usv-2 a little east: something to watch
    p3 = console.position(world, "demo-usv-3")
    frame3 = LocalFrame(p3["lat"], p3["lon"])
    square = [frame3.to_latlon(e, n) for e, n in ((30, 0), (30, 30), (0, 30), (0, 0))] * 3
    world.fleet.submit(
        world.tokens["ana"], world.instances["demo-usv-3"], "follow_path",
        {"waypoints": [{"lat": a, "lon": o} for a, o in square]},
    )  # fmt: skip
    p2 = console.position(world, "demo-usv-2")
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
    console.log_in(page, "ana")
    expect(page.locator("#who")).to_have_text("ana · operator")
    for vehicle_id in console.ALL:
        expect(console.marker(page, vehicle_id)).to_have_attribute("data-presence", "online")
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
        stored = console.position(world, "demo-usv-3")
        assert distance_m(*after, stored["lat"], stored["lon"]) < 15  # the same vehicle, live
        # the arrow points along the heading of the sample that put the marker there
        turned = console.marker(page, "demo-usv-3").locator("path").get_attribute("transform")
        shown = float(re.fullmatch(r"rotate\((.+)\)", turned or "")[1])
        sample = wait_until(lambda: stored_sample(world, "demo-usv-3", after), "that sample")
        assert shown == sample["heading_deg"]
        page.wait_for_function(  # a trail grows, sample by sample
            "fleetConsole.fleet.vehicles.get('demo-usv-3').trail.length >= 4"
        )
    console.assert_labels_apart(page)
    shots(page, "moving")

    # zoomed far out, the three markers crowd together: the labels still keep apart
    p1 = console.position(world, "demo-usv-1")
    console.centre_on(page, p1["lat"], p1["lon"], 14)
    console.assert_labels_apart(page)
    shots(page, "labels-zoomed-out")


def test_replay_puts_each_marker_where_the_store_has_it(
    world: World, open_console: Any, shots: Shots
) -> None:
    page, _ = open_console()
    console.log_in(page, "ana")
    page.click('[data-tab="replay"]')
    # nothing selected: every vehicle is offered ticked, however the fleet arrived
    expect(page.locator("#replay-vehicles input:checked")).to_have_count(len(console.ALL))
    page.click('button[data-minutes="5"]')
    for vehicle_id in console.ALL:
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
    first = min(console.ms(p["ts"]) for points in stored.values() for p in points)
    last = max(console.ms(p["ts"]) for points in stored.values() for p in points)
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
            x, y = console.screen_point(page, *want)
            assert abs(box["x"] + box["width"] / 2 - x) < 1.5
            assert abs(box["y"] + box["height"] / 2 - y) < 1.5
        shots(page, f"replay-at-{int(fraction * 100)}")

    # a jump over the whole recording lights only the newest event it passed, not each
    slider.fill(str(int(first - start)))
    slider.fill(str(int(last - start)))
    lit = page.evaluate(
        """() => [document.querySelectorAll('#timeline-ticks .tick.passed').length,
                  document.querySelectorAll('#timeline-ticks .tick.hit').length,
                  document.querySelectorAll('#replay-events li.hit').length]"""
    )
    assert lit[0] >= 2 and lit[1:] == [1, 1], lit

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
    assert re.fullmatch(
        r"fleet-replay-H2OmniX-Bravo_H2OmniX-Charlie-\d{4}-\d\d-\d\dT\d{6}Z\.gpx",
        got.value.suggested_filename,
    )
    gpx = ET.parse(got.value.path())
    ns = {"g": "http://www.topografix.com/GPX/1/1"}
    tracks = gpx.getroot().findall("g:trk", ns)
    assert sorted(t.findtext("g:name", namespaces=ns) for t in tracks) == [
        "H2OmniX Bravo (demo-usv-2)", "H2OmniX Charlie (demo-usv-3)",
    ]  # fmt: skip
    for t in tracks:
        vehicle_id = t.findtext("g:name", namespaces=ns).split("(")[1].rstrip(")")
        assert len(t.findall(".//g:trkpt", ns)) == len(stored[vehicle_id])
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
    expect(console.marker(page, "demo-usv-1")).to_be_visible()


def test_a_lost_link_shows_and_comes_back(world: World, open_console: Any, shots: Shots) -> None:
    page, _ = open_console(timezone_id="Europe/Zagreb")  # a browser an hour east of UTC
    console.log_in(page, "ana")
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

    def readings_greyed(want: bool) -> None:
        """Every battery reading and link delay in the fleet list greyed (``want``) or not:
        while the link is lost they are as last heard, like the presence badges."""
        page.wait_for_function(
            """want => {
                 const probe = document.createElement('span');
                 probe.style.color = 'var(--muted)';
                 document.getElementById('app').append(probe);
                 const muted = getComputedStyle(probe).color;
                 probe.remove();
                 const cells = [...document.querySelectorAll(
                   '.fleet-table td.reading, .fleet-table .link-delay')];
                 return cells.length >= 2
                   && cells.every(el => (getComputedStyle(el).color === muted) === want);
               }""",
            arg=want,
            timeout=10_000,
        )

    marked("none")
    readings_greyed(False)
    # What the whole console says on each change of the link's state, recorded as it is made.
    page.evaluate(
        """() => {
             window.linkSeen = [];
             new MutationObserver(() => window.linkSeen.push([
               document.getElementById('link').dataset.state,
               document.getElementById('app').dataset.link,
             ])).observe(document.getElementById('link'), { attributes: true });
           }"""
    )
    world.server.stop(grace_s=5.0)
    expect(page.locator("#link")).to_have_attribute("data-state", "lost")
    expect(page.locator("#link")).to_contain_text("link lost")
    marked('"?"')  # presence as last heard, not vouched for
    readings_greyed(True)
    # a try to connect again is made within a second or two: the view stays "lost" meanwhile
    page.wait_for_function(
        "() => window.linkSeen.some(([state]) => state === 'connecting')", timeout=10_000
    )
    marked('"?"')
    readings_greyed(True)
    # the wait before the next try counts down (it stood still, then jumped)
    page.wait_for_function(
        """() => /reconnecting in ([3-9]|\\d\\d) s$/
                   .test(document.getElementById('link').textContent)""",
        timeout=30_000,
    )
    waiting = int(page.locator("#link").inner_text().split()[-2])
    expect(page.locator("#link")).to_have_text(
        f"link lost · reconnecting in {waiting - 1} s", timeout=2_500
    )
    shots(page, "link-lost")
    world.server.start()  # the same port and store; the agents find it again
    expect(page.locator("#link")).to_have_attribute("data-state", "live", timeout=30_000)
    expect(page.locator("#link")).to_have_text("live")
    seen = page.evaluate("() => window.linkSeen")
    assert [app for state, app in seen if state == "connecting"] and all(
        app == "lost" for state, app in seen if state == "connecting"
    ), seen
    # the vehicles come back online in the view, from the socket again
    for vehicle_id in console.ALL:
        expect(console.marker(page, vehicle_id)).to_have_attribute(
            "data-presence", "online", timeout=30_000
        )
    marked("none")
    readings_greyed(False)
    shots(page, "link-back")


def test_a_network_gone_silent_is_a_lost_link_within_25_s(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A phone out of signal: the socket neither answers nor closes. The console's own
    check (15 s, then 10 s for the answer) says so; it used to stay "live", every boat
    green, until the network came back."""
    page, _ = open_console()
    console.log_in(page, "ana")
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
    before = [p for p in points if console.ms(p["ts"]) <= t]
    assert before, "the cursor is before the first sample"
    a = before[-1]
    later = [p for p in points if console.ms(p["ts"]) > t]
    if (
        not later
        or console.ms(a["ts"]) == t
        or console.ms(later[0]["ts"]) - console.ms(a["ts"]) > 30_000
    ):
        return a["lat"], a["lon"]
    b = later[0]
    f = (t - console.ms(a["ts"])) / (console.ms(b["ts"]) - console.ms(a["ts"]))
    return a["lat"] + (b["lat"] - a["lat"]) * f, a["lon"] + (b["lon"] - a["lon"]) * f


def test_expected_at_is_the_stored_sample_on_its_time() -> None:
    points = [
        {"ts": "2026-01-01T00:00:00.000Z", "lat": 1.0, "lon": 2.0},
        {"ts": "2026-01-01T00:00:10.000Z", "lat": 2.0, "lon": 4.0},
    ]
    t0 = console.ms(points[0]["ts"])
    assert expected_at(points, t0) == (1.0, 2.0)
    assert expected_at(points, t0 + 5000) == (1.5, 3.0)
    assert expected_at(points, t0 + 20_000) == (2.0, 4.0)
    assert math.isclose(expected_at(points, t0 + 10_000)[0], 2.0)
