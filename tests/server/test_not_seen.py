"""What a caller may not see is not found: for every route and op that names a vehicle,
an instance or a command, a caller without access to it gets exactly the answer an id
that does not exist gets (docs/security.md, "What a caller may not see: 404")."""

from __future__ import annotations

import json
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

import httpx
import pytest

from tests.factories import ADMIN, make_user, make_vehicle, sample, start_instance
from tests.live import call, connect

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")

NO_VEHICLE = "usv-none-0"
NO_INSTANCE = "i-0000000000000000"
NO_COMMAND = "c-0000000000000000"

#: Ask one route about one id; the answer's status and error body.
Ask = Callable[[str], Awaitable[tuple[int, dict[str, Any]]]]


@dataclass
class Fleet:
    """A vehicle with an instance, telemetry, a lease, a queued command and a pending
    control request, and callers who may not see any of it."""

    vehicle_id: str
    instance_id: str
    command_id: str
    operator: dict[str, str]  # an operator with no vehicles
    viewer: dict[str, str]  # a viewer with no vehicles
    manager: dict[str, str]  # a manager of no vehicle
    other_vehicle: dict[str, str]  # another vehicle's token

    def hidden(self) -> list[str]:
        """What the answers must not tell: the vehicle behind the instance and command."""
        return [self.vehicle_id]


@pytest.fixture
async def fleet(api: httpx.AsyncClient) -> Fleet:
    vid, vh = await make_vehicle(api)
    iid = (await start_instance(api, vid, vh))["instance_id"]
    body = {"instance_id": iid, "samples": [sample(1)]}
    assert (await api.post("/upper/update_param", headers=vh, json=body)).status_code == 200
    holder, holder_h = await make_user(api, "operator", [vid])
    _, asker = await make_user(api, "operator", [vid])
    grant = {"instance_id": iid, "user": holder, "duration_s": 600}
    assert (await api.post("/client/grant_control", headers=ADMIN, json=grant)).status_code == 200
    go = {"type": "go_to", "args": {"lat": 43.95, "lon": 15.45}}
    r = await api.post(
        "/client/submit_control", headers=holder_h, json={"instance_ids": [iid], "command": go}
    )
    assert r.status_code == 202, r.text
    ref = {"instance_id": iid}
    assert (await api.post("/client/request_control", headers=asker, json=ref)).status_code == 200
    return Fleet(
        vehicle_id=vid,
        instance_id=iid,
        command_id=r.json()["commands"][0]["command_id"],
        operator=(await make_user(api, "operator", []))[1],
        viewer=(await make_user(api, "viewer", []))[1],
        manager=(await make_user(api, "manager", []))[1],
        other_vehicle=(await make_vehicle(api))[1],
    )


def _shape(error: dict[str, Any], asked: str) -> str:
    """The error with the id the caller named written ``<id>``: what must not differ."""
    return json.dumps(error, sort_keys=True).replace(asked, "<id>")


async def _differences(asks: dict[str, tuple[Ask, str, str]], hidden: list[str]) -> list[str]:
    """For each route: ask about the id the caller may not see, then about one that does
    not exist; what differs (status, code, message, details) or tells too much."""
    out = []
    for name, (ask, real, unknown) in asks.items():
        (seen_status, seen), (missing_status, missing) = await ask(real), await ask(unknown)
        if seen_status != missing_status or _shape(seen, real) != _shape(missing, unknown):
            out.append(f"{name}: {seen_status} {seen} but {missing_status} {missing}")
        elif seen_status != 404 or seen.get("code") != "not_found":
            out.append(f"{name}: {seen_status} {seen}, not 404 not_found")
        elif any(secret in _shape(seen, real) for secret in hidden):
            out.append(f"{name}: {seen} names what the caller may not see")
    return out


def _http(
    api: httpx.AsyncClient, method: str, path: str, headers: dict[str, str], **kw: Any
) -> Ask:
    """A route asked about ``{id}``, placed in the path, the query or the body."""

    def fill(value: Any, ident: str) -> Any:
        if isinstance(value, str):
            return value.replace("{id}", ident)
        if isinstance(value, dict):
            return {k: fill(v, ident) for k, v in value.items()}
        if isinstance(value, list):
            return [fill(v, ident) for v in value]
        return value

    async def ask(ident: str) -> tuple[int, dict[str, Any]]:
        r = await api.request(method, fill(path, ident), headers=headers, **fill(kw, ident))
        error: dict[str, Any] = r.json().get("error") or {"answer": r.json()}
        return r.status_code, error

    return ask


async def test_users_get_for_what_they_may_not_see_what_they_get_for_nothing(
    api: httpx.AsyncClient, fleet: Fleet
) -> None:
    op, viewer, boss = fleet.operator, fleet.viewer, fleet.manager
    v, i, c = (
        (fleet.vehicle_id, NO_VEHICLE),
        (fleet.instance_id, NO_INSTANCE),
        (
            fleet.command_id,
            NO_COMMAND,
        ),
    )
    stop = {"type": "stop", "args": {}}
    go = {"type": "go_to", "args": {"lat": 43.95, "lon": 15.45}}
    asks: dict[str, tuple[Ask, str, str]] = {
        "GET /api/vehicles/{id}": (_http(api, "GET", "/api/vehicles/{id}", viewer), *v),
        "GET /api/vehicles/{id}/track": (
            _http(api, "GET", "/api/vehicles/{id}/track", viewer),
            *v,
        ),
        "GET .../track?format=gpx": (
            _http(api, "GET", "/api/vehicles/{id}/track", viewer, params={"format": "gpx"}),
            *v,
        ),
        "GET /api/vehicles/{id}/telemetry": (
            _http(api, "GET", "/api/vehicles/{id}/telemetry", viewer),
            *v,
        ),
        "GET /api/events?vehicle_id=": (
            _http(api, "GET", "/api/events", viewer, params={"vehicle_id": "{id}"}),
            *v,
        ),
        "POST /client/connect_instance (vehicle_id)": (
            _http(api, "POST", "/client/connect_instance", viewer, json={"vehicle_id": "{id}"}),
            *v,
        ),
        "POST /client/connect_instance (instance_id)": (
            _http(api, "POST", "/client/connect_instance", viewer, json={"instance_id": "{id}"}),
            *i,
        ),
        "GET /client/get_param": (
            _http(api, "GET", "/client/get_param", viewer, params={"instance_id": "{id}"}),
            *i,
        ),
        "GET /client/get_fbmessage": (
            _http(api, "GET", "/client/get_fbmessage", viewer, params={"instance_id": "{id}"}),
            *i,
        ),
        "GET /client/control_requests?instance_id=": (
            _http(api, "GET", "/client/control_requests", boss, params={"instance_id": "{id}"}),
            *i,
        ),
        "POST /client/submit_control (stop)": (
            _http(
                api,
                "POST",
                "/client/submit_control",
                op,
                json={"instance_ids": ["{id}"], "command": stop},
            ),
            *i,
        ),
        "POST /client/submit_control (go_to)": (
            _http(
                api,
                "POST",
                "/client/submit_control",
                op,
                json={"instance_ids": ["{id}"], "command": go},
            ),
            *i,
        ),
        "POST /client/request_control": (
            _http(api, "POST", "/client/request_control", op, json={"instance_id": "{id}"}),
            *i,
        ),
        "POST /client/grant_control": (
            _http(
                api,
                "POST",
                "/client/grant_control",
                boss,
                json={"instance_id": "{id}", "user": "anyone", "duration_s": 60},
            ),
            *i,
        ),
        "POST /client/revoke_control": (
            _http(api, "POST", "/client/revoke_control", boss, json={"instance_id": "{id}"}),
            *i,
        ),
        "POST /client/release_control": (
            _http(api, "POST", "/client/release_control", op, json={"instance_id": "{id}"}),
            *i,
        ),
        "POST /client/cancel_command": (
            _http(api, "POST", "/client/cancel_command", op, json={"command_id": "{id}"}),
            *c,
        ),
        "GET /api/commands/{id}": (_http(api, "GET", "/api/commands/{id}", viewer), *c),
    }
    assert await _differences(asks, fleet.hidden()) == []
    # Nothing was done on the way: the command still waits, the lease still holds.
    command = (await api.get(f"/api/commands/{fleet.command_id}", headers=ADMIN)).json()
    assert command["status"] == "queued"
    vehicle = (await api.get(f"/api/vehicles/{fleet.vehicle_id}", headers=ADMIN)).json()
    assert vehicle["control"] is not None


async def test_a_vehicle_asking_about_another_ones_instance_gets_what_it_gets_for_none(
    api: httpx.AsyncClient, fleet: Fleet
) -> None:
    vh, i = fleet.other_vehicle, (fleet.instance_id, NO_INSTANCE)
    ref = {"instance_id": "{id}"}
    asks: dict[str, tuple[Ask, str, str]] = {
        "POST /upper/heartbeat": (_http(api, "POST", "/upper/heartbeat", vh, json=ref), *i),
        "POST /upper/update_param": (
            _http(api, "POST", "/upper/update_param", vh, json={**ref, "samples": [sample(9)]}),
            *i,
        ),
        "GET /upper/get_control": (
            _http(api, "GET", "/upper/get_control", vh, params=ref),
            *i,
        ),
        "POST /upper/update_fbmessage": (
            _http(api, "POST", "/upper/update_fbmessage", vh, json={**ref, "acks": []}),
            *i,
        ),
        "POST /upper/finish_instance": (
            _http(api, "POST", "/upper/finish_instance", vh, json=ref),
            *i,
        ),
    }
    assert await _differences(asks, fleet.hidden()) == []
    r = await api.get("/client/get_param", headers=ADMIN, params={"instance_id": fleet.instance_id})
    assert r.json()["position"]["seq"] == 1  # the other vehicle's sample went nowhere


async def test_socket_ops_naming_an_instance_get_what_they_get_for_none(
    base: str, api: httpx.AsyncClient, fleet: Fleet
) -> None:
    ops: dict[str, dict[str, Any]] = {
        "heartbeat": {},
        "update_param": {"samples": [sample(9)]},
        "update_fbmessage": {"acks": []},
        "finish_instance": {},
    }
    async with await connect(base, "/ws/vehicle", _token(fleet.other_vehicle)) as ws:

        def over_socket(op: str, fields: dict[str, Any]) -> Ask:
            async def ask(ident: str) -> tuple[int, dict[str, Any]]:
                ack = await call(ws, op, f"{op}-{ident}", instance_id=ident, **fields)
                assert ack["ok"] is False, ack
                error: dict[str, Any] = ack["error"]
                return 404 if error["code"] == "not_found" else 0, error

            return ask

        asks: dict[str, tuple[Ask, str, str]] = {
            f"/ws/vehicle {op}": (over_socket(op, fields), fleet.instance_id, NO_INSTANCE)
            for op, fields in ops.items()
        }
        assert await _differences(asks, fleet.hidden()) == []
    # A user's subscription names a vehicle in its topic: refused alike, seen or not.
    async with await connect(base, "/ws/client", _token(fleet.viewer)) as ws:
        answers = [
            await call(ws, "subscribe", str(n), topics=[f"vehicle/{vid}/telemetry"])
            for n, vid in enumerate((fleet.vehicle_id, NO_VEHICLE))
        ]
    assert [a["ok"] for a in answers] == [False, False]
    assert _shape(answers[0]["error"], fleet.vehicle_id) == _shape(answers[1]["error"], NO_VEHICLE)


def _token(headers: dict[str, str]) -> str:
    return headers["Authorization"].removeprefix("Bearer ")
