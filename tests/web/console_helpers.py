"""What the console's browser tests do and read (``tests/web/``): log in, find a vehicle's
marker and where a position is on the page, move the map, read the fleet's commands and
leases from the server, measure boxes on the page and read the server's times. The
fixtures (``world``, ``open_console``, ``shots``) are in ``conftest.py``."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from playwright.sync_api import expect

from tests.agent.procs import wait_until
from tests.web.conftest import PASSWORD, World

ALL = ("demo-usv-1", "demo-usv-2", "demo-usv-3")


def log_in(page: Any, username: str, markers: int | None = 3) -> None:
    """Log in with the password; until the link is live and ``markers`` vehicles are on the
    map (the demo's three; None: not counted)."""
    page.goto("/")
    page.fill("#login-user", username)
    page.fill("#login-password", PASSWORD)
    page.click("#login-form button[type=submit]")
    expect(page.locator("#link")).to_have_attribute("data-state", "live")
    if markers is not None:
        expect(page.locator(".vicon[data-vehicle]")).to_have_count(markers)


def marker(page: Any, vehicle_id: str) -> Any:
    return page.locator(f'.vicon:not(.replay)[data-vehicle="{vehicle_id}"]')


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


def click_map(page: Any, lat: float, lon: float) -> None:
    """Click the map at (lat, lon) as a user would, closing first any toast over that point
    (a click on a toast is the toast's, not the map's)."""
    x, y = screen_point(page, lat, lon)
    for close in page.locator("#toasts .toast .close").all():
        box = close.locator("xpath=..").bounding_box()
        if (
            box
            and box["x"] <= x <= box["x"] + box["width"]
            and box["y"] <= y <= box["y"] + box["height"]
        ):
            close.click()
    page.mouse.click(x, y)


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


def polygon(corners: list[tuple[float, float]]) -> dict[str, Any]:
    """A GeoJSON Polygon (as ``/api/zones`` and ``/api/obstacles`` take it) through the
    corners, (lat, lon) each, its ring closed."""
    ring = [[lon, lat] for lat, lon in corners]
    return {"type": "Polygon", "coordinates": [[*ring, ring[0]]]}


def ms(ts: str) -> float:
    return datetime.fromisoformat(ts.replace("Z", "+00:00")).timestamp() * 1000


def lease_of(world: World, instance: str) -> Any:
    body = {"instance_id": instance}
    return world.fleet.call("POST", "/client/connect_instance", json=body)["instance"]["control"]


def box_of(locator: Any) -> dict[str, float]:
    """Where it is on the page (a panel drawn again on every sample replaces its buttons:
    one may be gone between finding and measuring it)."""
    return wait_until(locator.bounding_box, "it to be shown", 15)


def local_times(page: Any, *hours_ago: float) -> list[str]:
    """The page's local times ``hours_ago`` hours before its now, as the replay's fields are
    typed: ``2026-11-26 14:05:00`` (24-hour, the browser's zone)."""
    texts: list[str] = page.evaluate(
        """(hours) => hours.map((h) => {
            const t = Date.now() - h * 3600000;
            return new Date(t - new Date(t).getTimezoneOffset() * 60000)
                .toISOString().slice(0, 19).replace("T", " ");
        })""",
        list(hours_ago),
    )
    return texts


def replay_up(page: Any) -> None:
    """Until the replay's module is loaded (after the page: its form is not yet handled)."""
    page.wait_for_function("() => Boolean(window.fleetConsole && fleetConsole.replay)")
