"""Test-data factories: each test builds the world it needs through the public API."""

from __future__ import annotations

import itertools
from datetime import UTC, datetime, timedelta
from typing import Any

import httpx

ADMIN_TOKEN = "fct_test-admin-token-0123456789"
_ids = itertools.count(1)


class FakeClock:
    """A clock the test moves by hand: expiry and presence without waiting."""

    def __init__(self, start: datetime | None = None) -> None:
        self.now = start or datetime(2026, 11, 22, 10, 0, 0, tzinfo=UTC)

    def __call__(self) -> datetime:
        return self.now

    def advance(self, seconds: float) -> None:
        self.now += timedelta(seconds=seconds)


def bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


ADMIN = bearer(ADMIN_TOKEN)


def unique(prefix: str) -> str:
    return f"{prefix}-{next(_ids)}"


async def make_vehicle(
    client: httpx.AsyncClient, vehicle_id: str | None = None, vehicle_type: str = "usv"
) -> tuple[str, dict[str, str]]:
    """Register a vehicle; returns its id and its auth header."""
    vehicle_id = vehicle_id or unique("usv")
    r = await client.post(
        "/api/vehicles",
        headers=ADMIN,
        json={"vehicle_id": vehicle_id, "name": vehicle_id.upper(), "vehicle_type": vehicle_type},
    )
    assert r.status_code == 201, r.text
    return vehicle_id, bearer(r.json()["token"])


async def make_user(
    client: httpx.AsyncClient,
    role: str = "operator",
    vehicles: list[str] | None = None,
    username: str | None = None,
    password: str | None = None,
) -> tuple[str, dict[str, str]]:
    username = username or unique(role)
    body: dict[str, Any] = {"username": username, "role": role, "vehicles": vehicles or []}
    if password:
        body["password"] = password
    r = await client.post("/api/users", headers=ADMIN, json=body)
    assert r.status_code == 201, r.text
    return username, bearer(r.json()["token"])


async def start_instance(
    client: httpx.AsyncClient,
    vehicle_id: str,
    headers: dict[str, str],
    capabilities: list[str] | None = None,
    params: dict[str, Any] | None = None,
    name: str | None = None,
) -> dict[str, Any]:
    """Start the vehicle's instance; ``name``: the display name it announces (its id when
    not given)."""
    r = await client.post(
        "/upper/start_instance",
        headers=headers,
        json={
            "vehicle_id": vehicle_id,
            "name": vehicle_id if name is None else name,
            "vehicle_type": "usv",
            "capabilities": ["stop", "go_to", "keep_station", "follow_path"]
            if capabilities is None
            else capabilities,
            "params": params or {},
        },
    )
    assert r.status_code == 200, r.text
    result: dict[str, Any] = r.json()
    return result


def sample(
    seq: int, ts: datetime | None = None, lat: float = 43.94, lon: float = 15.44, **extra: Any
) -> dict[str, Any]:
    ts = ts or datetime(2026, 11, 22, 10, 0, 0, tzinfo=UTC) + timedelta(seconds=seq)
    return {
        "seq": seq,
        "ts": ts.isoformat().replace("+00:00", "Z"),
        "lat": lat,
        "lon": lon,
        **extra,
    }


def make_dead_letters(store: Any, clock: Any) -> Any:
    """The dead letters of a store, for a service built by hand in a test (not counted)."""
    from server.services.dead_letters import DeadLetters
    from server.storage.dead_letters import DeadLettersRepo

    return DeadLetters(DeadLettersRepo(store), lambda _loop: None, clock)
