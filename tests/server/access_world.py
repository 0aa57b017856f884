"""Who may call what (``test_access_routes.py``, ``test_access_sockets.py``): the kinds of
caller, and the world each cell of the matrix runs in (fresh ids, so that one caller's
success does not change the next one's answer).

Callers: no token, a viewer, an operator holding the vehicle's lease, the vehicle's
field manager, an admin, the vehicle, a foreign vehicle, a gateway listing the vehicle, a
revoked token and an expired one.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from datetime import timedelta
from typing import Any

import httpx

from fleet_protocol import utcnow
from server.services.tokens import digest, new_token
from tests.factories import ADMIN, bearer

CALLERS = (
    "anon",
    "viewer",
    "operator",
    "manager",
    "admin",
    "vehicle",
    "foreign",
    "gateway",
    "revoked",
    "expired",
)
_n = itertools.count(1)
PASSWORD = "correct horse battery"


@dataclass
class World:
    """One cell's world: a vehicle (its instance, lease held by the operator, a command, a
    pending request), a foreign vehicle, a gateway, people, an obstacle, dead tokens."""

    n: int
    vid: str
    iid: str
    command_id: str
    gateway_id: str
    obstacle_id: str
    zone_id: str
    password_user: str
    tokens: dict[str, str | None]

    def headers(self, caller: str) -> dict[str, str]:
        token = self.tokens[caller]
        return bearer(token) if token else {}


async def build(c: httpx.AsyncClient, app: Any) -> World:
    n = next(_n)
    tokens: dict[str, str | None] = {"anon": None, "admin": ADMIN["Authorization"][7:]}

    async def post(path: str, body: dict[str, Any], headers: dict[str, str] = ADMIN) -> Any:
        r = await c.post(path, headers=headers, json=body)
        assert r.is_success, (path, r.text)
        return r.json()

    vid, fid, gid = f"mv-{n}", f"mf-{n}", f"mg-{n}"
    tokens["vehicle"] = (await post("/api/vehicles", {"vehicle_id": vid}))["token"]
    tokens["foreign"] = (await post("/api/vehicles", {"vehicle_id": fid}))["token"]
    tokens["gateway"] = (await post("/api/gateways", {"gateway_id": gid, "vehicles": [vid]}))[
        "token"
    ]
    caps = ["stop", "go_to", "keep_station", "follow_path"]
    vh = bearer(tokens["vehicle"] or "")
    iid = (await post("/upper/start_instance", {"vehicle_id": vid, "capabilities": caps}, vh))[
        "instance_id"
    ]
    await post("/upper/start_instance", {"vehicle_id": fid}, bearer(tokens["foreign"] or ""))
    for role in ("viewer", "operator", "manager"):
        body = {"username": f"{role}-{n}", "role": role, "vehicles": [vid]}
        tokens[role] = (await post("/api/users", body))["token"]
    revoked = (await post("/api/users", {"username": f"gone-{n}", "role": "operator"}))["token"]
    await post(f"/api/users/gone-{n}/revoke_tokens", {})
    tokens["revoked"] = revoked
    password_user = "pw"  # one per app (hashing a password costs a tenth of a second)
    if (await c.get("/api/users/pw", headers=ADMIN)).status_code == 404:
        await post(
            "/api/users", {"username": password_user, "role": "viewer", "password": PASSWORD}
        )
    tokens["expired"] = await expired_session(app, f"viewer-{n}")
    await post(
        "/client/grant_control",
        {"instance_id": iid, "user": f"operator-{n}", "duration_s": 600},
    )
    command_id = (
        await post(
            "/client/submit_control",
            {"instance_ids": [iid], "command": {"type": "go_to", "args": {"lat": 1, "lon": 2}}},
            bearer(tokens["operator"] or ""),
        )
    )["commands"][0]["command_id"]
    await post("/client/request_control", {"instance_id": iid}, bearer(tokens["manager"] or ""))
    polygon = {"type": "Polygon", "coordinates": [[[1, 1], [1, 2], [2, 2], [2, 1], [1, 1]]]}
    obstacle_id = (await post("/api/obstacles", {"name": "pier", "polygon": polygon}))[
        "obstacle_id"
    ]
    far = {"type": "Polygon", "coordinates": [[[10, 10], [10, 11], [11, 11], [11, 10], [10, 10]]]}
    zone_id = (await post("/api/zones", {"name": "reef", "kind": "no_go", "polygon": far}))[
        "zone_id"
    ]
    return World(n, vid, iid, command_id, gid, obstacle_id, zone_id, password_user, tokens)


async def expired_session(app: Any, username: str) -> str:
    """A session token of ``username`` that expired a minute ago (as /auth/token makes them)."""
    token = new_token()
    now = utcnow()
    await app.state.services.auth.repo.insert_token(
        {
            "token_id": f"t-exp-{username}",
            "digest": digest(token),
            "kind": "user",
            "subject": username,
            "purpose": "session",
            "created_at": now - timedelta(hours=1),
            "expires_at": now - timedelta(minutes=1),
            "revoked_at": None,
        }
    )
    return token
