"""The console in a real browser: Debian's chromium, headless, driven by Playwright, against
a real ``fleet-server`` process with the demo's three simulated vehicles.

One server and one browser per module (starting them is most of the time); each test
opens its own browser context (its own session storage: it logs in) and saves a
screenshot per step in its own output folder (``tmp_path``), also copied to
``$FLEET_WEB_SHOTS`` when that is set. The browser may reach the server only: every
request to another host is refused and fails the test (the console must work with no
internet).
"""

from __future__ import annotations

import os
import re
import shutil
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from server.demo import VEHICLES
from tests.agent.procs import AgentProcess, Fleet, ServerProcess

CHROMIUM = Path("/usr/bin/chromium")
#: Headless on a machine with no network: nothing in the background may reach out.
CHROMIUM_FLAGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-dev-shm-usage",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-quic",
    "--no-first-run",
]
WEB_MODULES = Path(__file__).resolve().parents[2] / "server" / "web" / "node_modules"
PASSWORD = "a long harbour password"
#: Any http(s) URL whose host is not the loopback the server listens on.
ELSEWHERE = re.compile(r"^https?://(?!(127\.0\.0\.1|localhost)(:[0-9]+)?/)")
TIME_SCALE = 4  # the simulated vehicles run four times faster (2 m/s at full speed)


@dataclass
class World:
    server: ServerProcess
    fleet: Fleet
    agents: list[AgentProcess]
    tokens: dict[str, str] = field(default_factory=dict)  # username -> API token
    instances: dict[str, str] = field(default_factory=dict)  # vehicle_id -> instance_id

    def as_user(self, username: str, method: str, path: str, **kw: Any) -> Any:
        return self.fleet.call(method, path, self.tokens[username], **kw)


@contextmanager
def served_world(
    workdir: Path,
    vehicles: list[tuple[str, str, float, float]],
    people: list[tuple[str, str]],
) -> Iterator[World]:
    """A server, ``vehicles`` (id, name, lat, lon) simulated there, and ``people``
    (username, role) who may see them all and log in with the password; the first person
    holds every vehicle."""
    server = ServerProcess(workdir)
    server.start()
    fleet = Fleet(server)
    world = World(server, fleet, [])
    ids = [v[0] for v in vehicles]
    try:
        for vehicle_id, name, lat, lon in vehicles:
            token = fleet.call(
                "POST",
                "/api/vehicles",
                json={"vehicle_id": vehicle_id, "name": name, "vehicle_type": "usv"},
            )["token"]
            agent = AgentProcess(
                server, token, vehicle_id, workdir / f"{vehicle_id}.outbox",
                adapter="sim", start=f"{lat},{lon}", rate_hz=2, time_scale=TIME_SCALE,
            )  # fmt: skip
            agent.start()
            world.agents.append(agent)
        for username, role in people:
            body = {"username": username, "role": role, "vehicles": ids, "password": PASSWORD}
            world.tokens[username] = fleet.call("POST", "/api/users", json=body)["token"]
        for vehicle_id in ids:
            world.instances[vehicle_id] = fleet.online_instance(vehicle_id)
            fleet.grant(world.instances[vehicle_id], people[0][0])
        yield world
    finally:
        for agent in world.agents:
            agent.stop()
        server.stop(grace_s=5.0)


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> Iterator[World]:
    """A server, the demo's three vehicles simulated, and three people who log in with a
    password: ``ana`` and ``ben`` (operators), ``mia`` (the field manager); ana holds
    every vehicle."""
    if not (WEB_MODULES / "leaflet" / "dist").is_dir():
        pytest.fail("server/web/node_modules is missing: run `make web` (npm ci in server/web)")
    people = [("ana", "operator"), ("ben", "operator"), ("mia", "manager")]
    with served_world(tmp_path_factory.mktemp("console-server"), list(VEHICLES), people) as w:
        yield w


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    if not CHROMIUM.exists():  # fail, never skip: CI installs it (.ci/run)
        pytest.fail(
            f"{CHROMIUM} is missing: apt-get install chromium (the console's tests need it)"
        )
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        chromium = p.chromium.launch(
            executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_FLAGS
        )
        yield chromium
        chromium.close()


class Shots:
    """Screenshots of one test's steps, numbered in order."""

    def __init__(self, folder: Path, test_name: str) -> None:
        self.folder = folder
        self.test_name = test_name
        self.n = 0
        self.saved: list[Path] = []

    def __call__(self, page: Any, step: str, **kw: Any) -> Path:
        self.n += 1
        path = self.folder / f"{self.n:02d}-{step}.png"
        page.screenshot(path=str(path), **kw)
        self.saved.append(path)
        extra = os.environ.get("FLEET_WEB_SHOTS")
        if extra:
            target = Path(extra) / self.test_name
            target.mkdir(parents=True, exist_ok=True)
            shutil.copy(path, target / path.name)
        return path


@pytest.fixture
def shots(tmp_path: Path, request: pytest.FixtureRequest) -> Shots:
    return Shots(tmp_path, request.node.name)


@dataclass
class Guard:
    """What a page did that it must not: reach another host, throw."""

    outside: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    requests: list[str] = field(default_factory=list)


@pytest.fixture
def open_console(
    browser: Any, world: World, tmp_path: Path
) -> Iterator[Callable[..., tuple[Any, Guard]]]:
    """open_console(viewport=(w, h), **context options) -> (page, guard). At the end each
    page's last state is saved (``last-N.png``) and its messages printed (pytest shows
    them when the test failed)."""
    contexts: list[tuple[Any, Guard]] = []

    def open_page(viewport: tuple[int, int] = (1366, 820), **options: Any) -> tuple[Any, Guard]:
        context = browser.new_context(
            viewport={"width": viewport[0], "height": viewport[1]},
            base_url=world.server.url,
            accept_downloads=True,
            **options,
        )
        guard = Guard()

        def refuse(route: Any) -> None:
            guard.outside.append(route.request.url)
            route.abort()

        # Only what is not for the server is intercepted (a pattern the browser's side
        # matches): a request held for a Python handler would wait until the test next
        # calls Playwright, and the console's calls to the server must not.
        context.route(ELSEWHERE, refuse)
        page = context.new_page()
        page.set_default_timeout(15_000)
        page.on("pageerror", lambda e: guard.errors.append(f"uncaught: {e}"))
        page.on("console", lambda m: _console_error(m, guard))
        page.on("request", lambda r: guard.requests.append(f"{r.method} {r.url}"))
        contexts.append((context, guard))
        return page, guard

    yield open_page
    for n, (context, guard) in enumerate(contexts):
        for page in context.pages:
            page.screenshot(path=str(tmp_path / f"last-{n}.png"))
            print(f"page {n} at the end: {page.url}; messages:")
            print(page.locator("#toasts").inner_text() if page.locator("#toasts").count() else "")
        context.close()
        assert guard.outside == [], f"the console reached outside the server: {guard.outside}"
        assert guard.errors == [], f"errors in the page: {guard.errors}"


def _console_error(message: Any, guard: Guard) -> None:
    # The browser logs every refused HTTP call ("Failed to load resource: ... 409") and
    # every socket it could not open (the server away) as an error; the console handles
    # those. Anything else logged as an error is a fault.
    expected = ("Failed to load resource", "WebSocket connection to")
    if message.type == "error" and not message.text.startswith(expected):
        guard.errors.append(message.text)


@contextmanager
def no_requests(guard: Guard) -> Iterator[None]:
    """Within the block the page made no HTTP request (the socket carries everything)."""
    before = len(guard.requests)
    yield
    made = guard.requests[before:]
    assert made == [], f"the console polled: {made}"
