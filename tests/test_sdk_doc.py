"""docs/sdk.md's table of calls, by the wire's names, against the server's real routes
and what the SDK calls: each route it names is one the server has (with that method),
each SDK call it names exists, and each call of a row asks exactly the row's routes
(``cancel`` was listed on a route the server never had)."""

from __future__ import annotations

import re
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import httpx

from remote_client.sdk import FleetClient
from server.app import create_app
from server.settings import Settings

SDK_DOC = Path(__file__).resolve().parents[1] / "docs" / "sdk.md"
ROUTE = re.compile(r"`(GET|POST|PUT|PATCH|DELETE) (/[^`\s]*)`")
CALL = re.compile(r"`(\w+)\(")
Route = tuple[str, str]

#: A call of each SDK method a row names that asks one request and takes any answer.
CALLS: dict[str, Callable[[FleetClient], Awaitable[Any]]] = {
    "vehicles": lambda f: f.vehicles(),
    "vehicle": lambda f: f.vehicle("usv-1"),
    "connect": lambda f: f.connect("i-1"),
    "params": lambda f: f.params("i-1"),
    "submit": lambda f: f.submit(["i-1"], {"type": "stop", "args": {}}),
    "stop": lambda f: f.stop(["i-1"]),
    "go_to": lambda f: f.go_to("i-1", 43.9, 15.4),
    "keep_station": lambda f: f.keep_station(["i-1"]),
    "follow_path": lambda f: f.follow_path("i-1", [(43.9, 15.4)]),
    "command": lambda f: f.command("c-1"),
    "cancel": lambda f: f.cancel("c-1"),
    "commands": lambda f: f.commands("i-1"),
    "request_control": lambda f: f.request_control("i-1"),
    "grant_control": lambda f: f.grant_control("i-1", "ana"),
    "deny_control": lambda f: f.deny_control("i-1", "ana"),
    "revoke_control": lambda f: f.revoke_control("i-1"),
    "release_control": lambda f: f.release_control("i-1"),
    "control_requests": lambda f: f.control_requests(),
    "event_log": lambda f: f.event_log(),
}


def _shape(path: str) -> str:
    """A path with each parameter alike: ``/api/commands/{}``."""
    return re.sub(r"\{[^}]*\}", "{}", path)


def _rows() -> list[tuple[set[Route], list[str]]]:
    """Each row of the table: the routes of its wire column, the SDK calls of the other."""
    text = SDK_DOC.read_text(encoding="utf-8")
    table = text.split("## The calls, by the wire's names", 1)[1].split("\n\n", 2)[1]
    rows = []
    for line in table.splitlines()[2:]:
        wire, sdk = line.strip("|").split(" | ", 1)
        routes = {(method, _shape(path)) for method, path in ROUTE.findall(wire)}
        rows.append((routes, CALL.findall(sdk)))
    return rows


def _server_routes() -> set[Route]:
    paths = create_app(Settings(_env_file=None)).openapi()["paths"]
    return {(method.upper(), _shape(path)) for path, ops in paths.items() for method in ops}


def test_every_route_docs_sdk_names_is_one_the_server_has() -> None:
    named = {route for method, path in ROUTE.findall(SDK_DOC.read_text(encoding="utf-8"))
             for route in [(method, _shape(path))]}  # fmt: skip
    assert named - _server_routes() == set()


async def test_each_row_s_calls_ask_the_row_s_routes() -> None:
    asked: list[Route] = []

    def answer(request: httpx.Request) -> httpx.Response:
        asked.append((request.method, request.url.path))
        return httpx.Response(200, json={})

    rows = _rows()
    assert len(rows) >= 10
    transport = httpx.MockTransport(answer)
    async with httpx.AsyncClient(transport=transport, base_url="http://fleet.test") as http:
        fleet = FleetClient("http://fleet.test", "fct_x", client=http)
        checked = set()
        for routes, calls in rows:
            covered = set()
            for name in calls:
                assert callable(getattr(fleet, name, None)), f"FleetClient has no {name}()"
                if name not in CALLS:
                    continue
                asked.clear()
                await CALLS[name](fleet)
                [(method, path)] = asked
                said = [
                    (m, p)
                    for m, p in routes
                    if m == method and re.fullmatch(p.replace("{}", "[^/]+"), path)
                ]
                assert said, f"{name}() asks {method} {path}; its row says {sorted(routes)}"
                covered.update(said)
                checked.add(name)
            if all(name in CALLS for name in calls):
                assert covered == routes, f"no call of {calls} asks {sorted(routes - covered)}"
    assert checked == set(CALLS)  # each call above is in the table
