"""What is wrong with a vehicle now, in a real browser (as test_console_commands): its
alarms (``VehicleView.alarms``) as red badges in the fleet table and a list at the top of
its panel, there as soon as the server sees them and gone when they end."""

from __future__ import annotations

import re
from typing import Any

import pytest
from playwright.sync_api import expect

from tests.web.conftest import Shots, World
from tests.web.console_helpers import log_in, marker

pytestmark = [pytest.mark.slow, pytest.mark.browser]


def test_a_low_battery_shows_in_the_table_and_the_panel_until_it_ends(
    world: World, open_console: Any, shots: Shots
) -> None:
    vehicle = "demo-usv-3"
    page, _ = open_console()
    log_in(page, "mia")
    page.click('[data-tab="fleet"]')
    row = page.locator(f'#fleet-table tr[data-vehicle="{vehicle}"]')
    expect(row.locator(".alarm")).to_have_count(0)

    # The simulated boats run on 100 % or less: a threshold of 100 % is a low battery.
    world.fleet.call("PUT", f"/api/vehicles/{vehicle}/failsafe", json={"low_battery_pct": 100.0})
    badge = row.locator(".alarm.a-low_battery")
    expect(badge).to_have_text("low battery", timeout=15_000)
    # since when, as the console says a time (this browser's clock, to the second)
    [alarm] = world.fleet.call("GET", f"/api/vehicles/{vehicle}")["alarms"]
    since = page.evaluate(
        "ts => new Date(Date.parse(ts)).toLocaleTimeString([], { hour12: false })",
        alarm["since"],
    )
    said = r"^battery low: \d+(\.\d)? % \(alarm below 100 %\) since " + re.escape(since) + "$"
    expect(badge).to_have_attribute("title", re.compile(said))
    expect(row).to_have_class(re.compile(r"\balarmed\b"))
    expect(row.locator("td").nth(3)).to_have_text(re.compile(r"^\d{1,2} %$"))  # below 100
    for other in ("demo-usv-1", "demo-usv-2"):
        expect(page.locator(f'#fleet-table tr[data-vehicle="{other}"] .alarm')).to_have_count(0)
        expect(marker(page, other)).not_to_have_class(re.compile(r"\balarmed\b"))
    # on the map too (a phone opens on it): a red halo and the alarm on the boat's label
    expect(marker(page, vehicle)).to_have_class(re.compile(r"\balarmed\b"))
    chip = marker(page, vehicle).locator(".alarm-chip")
    expect(chip).to_have_text("low battery")
    expect(chip).to_have_attribute("title", re.compile(said))  # since when, there too
    shots(page, "alarm-table")

    marker(page, vehicle).click()
    page.click('[data-tab="vehicle"]')
    expect(page.locator("#vehicle-pane .alarm-list li")).to_have_text(re.compile(said))
    shots(page, "alarm-panel")

    world.fleet.call("PUT", f"/api/vehicles/{vehicle}/failsafe", json={})  # no threshold
    expect(page.locator("#vehicle-pane .alarm-list")).to_have_count(0, timeout=15_000)
    page.click('[data-tab="fleet"]')
    expect(row.locator(".alarm")).to_have_count(0)
    expect(row).not_to_have_class(re.compile(r"\balarmed\b"))
    expect(marker(page, vehicle).locator(".alarm-chip")).to_have_count(0)


def test_a_zone_drawn_or_removed_while_the_console_is_open_is_drawn_or_gone(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A zone for every vehicle is said on the ``zones`` topic: an operator whose console
    was open saw it only after a reload, and was refused a path across a zone not drawn."""
    page, _ = open_console()
    log_in(page, "ana")
    zones = page.locator("path.zone-no_go")
    expect(zones).to_have_count(0)
    here = world.fleet.call("GET", "/api/vehicles/demo-usv-1")["position"]
    lat, lon = here["lat"], here["lon"]
    ring = [[lon + dx, lat + dy] for dx, dy in ((0.002, 0.002), (0.003, 0.002), (0.003, 0.003))]
    made = world.fleet.call(
        "POST",
        "/api/zones",
        json={
            "name": "Harbour mouth",
            "kind": "no_go",
            "polygon": {"type": "Polygon", "coordinates": [[*ring, ring[0]]]},
        },
    )
    expect(zones).to_have_count(1, timeout=10_000)
    shots(page, "zone-drawn")
    world.fleet.call("DELETE", f"/api/zones/{made['zone_id']}")
    expect(zones).to_have_count(0, timeout=10_000)


def test_a_manager_hears_of_stops_others_send_and_the_log_keeps_them(
    world: World, open_console: Any, shots: Shots
) -> None:
    """An operator's Stop all reached the boats; the field manager saw only labels change."""
    page, _ = open_console()
    log_in(page, "mia")
    ids = [world.instances[v] for v in ("demo-usv-1", "demo-usv-2")]
    world.as_user(
        "ana", "POST", "/client/submit_control",
        json={"instance_ids": ids, "command": {"type": "stop", "args": {}}},
    )  # fmt: skip
    told = page.locator("#toasts .toast", has_text="ana stopped")
    expect(told).to_have_count(1)  # one toast for the two
    expect(told).to_contain_text("ana stopped H2OmniX Alpha, H2OmniX Bravo")
    page.click('[data-tab="control"]')
    stops = page.locator('section.safety-log li[data-kind="command"]')
    expect(stops).to_have_count(2)
    expect(stops.first).to_contain_text("stop")
    shots(page, "stops-told")
