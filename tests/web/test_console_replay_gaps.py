"""A replay across a time the vehicle was out of contact, in a real browser (as
test_console_watch): the track was drawn as if continuous and the replay's clock just jumped.
The server's presence events (offline, then heard again) bound the gap now: the track
across it is dashed grey, the timeline has a grey band, the marker waits greyed where the
vehicle was last heard and the replay says "offline 10:02:11-10:05:40" (from the last
position heard to the first sign of it again). A world of its own
(the module's): its agent is stopped and started again."""

from __future__ import annotations

import re
from datetime import UTC, datetime
from typing import Any

import pytest
from playwright.sync_api import expect

from server.demo import VEHICLES
from tests.agent.procs import wait_until
from tests.web.conftest import Shots, World
from tests.web.console_helpers import log_in, ms
from vehicle_client.geo import LocalFrame, distance_m

pytestmark = [pytest.mark.slow, pytest.mark.browser]

VEHICLE = "demo-usv-2"


def events(world: World) -> list[dict[str, Any]]:
    params = {"vehicle_id": VEHICLE, "limit": 10000}
    return list(world.fleet.call("GET", "/api/events", params=params)["events"])


def track(world: World) -> list[dict[str, Any]]:
    return list(world.fleet.call("GET", f"/api/vehicles/{VEHICLE}/track")["points"])


def clock_re(epoch_ms: float) -> str:
    """The browser's clock() of that time in UTC (the hour with or without its zero)."""
    t = datetime.fromtimestamp(epoch_ms / 1000, UTC)
    return f"0?{t.hour}:{t:%M:%S}"


def test_a_replay_shows_when_a_vehicle_was_offline(
    world: World, open_console: Any, shots: Shots
) -> None:
    agent = world.agents[[v[0] for v in VEHICLES].index(VEHICLE)]
    here = world.fleet.position(world.instances[VEHICLE])
    there = LocalFrame(here["lat"], here["lon"]).to_latlon(0.0, 80.0)
    world.fleet.submit(
        world.tokens["ana"], world.instances[VEHICLE], "go_to", {"lat": there[0], "lon": there[1]}
    )

    def moved() -> bool:  # under way: the way across the gap is a line on the map
        p = track(world)[-1]
        return distance_m(p["lat"], p["lon"], here["lat"], here["lon"]) > 10

    wait_until(moved, "the vehicle under way")
    agent.stop()  # out of contact: offline after offline_after_s (10 s)

    def offline_event() -> dict[str, Any] | None:
        return next(
            (
                e
                for e in events(world)
                if e["kind"] == "presence" and e["data"]["presence"] == "offline"
            ),
            None,
        )

    went = wait_until(offline_event, "the vehicle to be offline")
    agent.start()

    def back_event() -> dict[str, Any] | None:  # the first sign of contact after it
        later = [e for e in events(world) if ms(e["at"]) > ms(went["at"])]
        return next(
            (
                e
                for e in later
                if e["kind"] == "instance"
                or (e["kind"] == "presence" and e["data"]["presence"] != "offline")
            ),
            None,
        )

    back = wait_until(back_event, "the vehicle back")
    off_ms, on_ms = ms(went["at"]), ms(back["at"])
    wait_until(lambda: sum(ms(p["ts"]) > on_ms for p in track(world)) >= 6, "positions after")
    last_heard = [p for p in track(world) if ms(p["ts"]) <= off_ms][-1]

    page, _ = open_console(timezone_id="UTC")
    log_in(page, "ana")
    page.click('[data-tab="replay"]')
    page.click('button[data-minutes="5"]')
    for vehicle_id, *_ in VEHICLES:
        page.locator(f'#replay-vehicles input[value="{vehicle_id}"]').set_checked(
            vehicle_id == VEHICLE
        )
    page.click("#replay-load")
    expect(page.locator("#replay-bar")).to_be_visible()
    # the way across the gap: dashed and grey, not the vehicle's colour
    dashed = page.locator(f"path.replay-offline-{VEHICLE}")
    expect(dashed).to_have_count(1)
    assert dashed.get_attribute("stroke-dasharray") == "6 8"
    band = page.locator(f'#timeline-gaps .gap[data-vehicle="{VEHICLE}"]')
    expect(band).to_have_count(1)
    start = page.evaluate("fleetConsole.replay.start")
    slider, status = page.locator("#replay-slider"), page.locator("#replay-status")
    replay_marker = page.locator(f'.vicon.replay[data-vehicle="{VEHICLE}"]')

    slider.fill(str(int((off_ms + on_ms) / 2 - start)))  # inside the gap
    # from the last position heard (the server marks it offline offline_after_s later)
    dash = "\u2013"  # an en dash between the times
    said = rf"^H2OmniX Bravo offline {clock_re(ms(last_heard['ts']))}{dash}{clock_re(on_ms)}$"
    expect(status).to_have_text(re.compile(said))
    expect(replay_marker).to_have_class(re.compile(r"\boffline\b"))
    # it waits where it was last heard: no gliding across the gap
    assert float(replay_marker.get_attribute("data-lat")) == last_heard["lat"]
    assert float(replay_marker.get_attribute("data-lon")) == last_heard["lon"]
    shots(page, "in-the-gap")

    slider.fill(str(int(on_ms + 2000 - start)))  # heard again
    expect(status).to_be_hidden()
    expect(replay_marker).not_to_have_class(re.compile(r"\boffline\b"))
    slider.fill(str(int(ms(last_heard["ts"]) - 3000 - start)))  # before it went
    expect(status).to_be_hidden()
    shots(page, "before-the-gap")
