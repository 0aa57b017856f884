"""The SDK's administration calls: users, vehicles, gateways and their tokens (admins);
zones, obstacles, failsafes and the dead letters. A part of
:class:`~remote_client.sdk.FleetClient`."""

from __future__ import annotations

from typing import Any

from remote_client.names import pick_named
from remote_client.sdk_session import Body, OneOrMany, Session, given, listed

__all__ = ["AdminCalls"]


class AdminCalls(Session):
    """The administration and safety-set-up routes (``docs/api.md``)."""

    # ---- administration (admins) -----------------------------------------------
    async def users(self) -> Body:
        """``{"users": [{username, role, vehicles, disabled, created_at}, ...]}``."""
        body: Body = await self.call("GET", "/api/users")
        return body

    async def create_user(
        self,
        username: str,
        role: str,
        vehicles: OneOrMany = (),
        *,
        password: str | None = None,
    ) -> Body:
        """``{username, role, token, vehicles}``: the token is shown this once."""
        body = given(username=username, role=role, vehicles=listed(vehicles), password=password)
        answer: Body = await self.call("POST", "/api/users", json=body)
        return answer

    async def update_user(
        self,
        username: str,
        *,
        role: str | None = None,
        vehicles: OneOrMany | None = None,
        disabled: bool | None = None,
        password: str | None = None,
    ) -> Body:
        """``PATCH /api/users/{username}``: only the fields given change; the user's view."""
        ids = listed(vehicles) if vehicles is not None else None
        body = given(role=role, vehicles=ids, disabled=disabled, password=password)
        answer: Body = await self.call("PATCH", f"/api/users/{username}", json=body)
        return answer

    async def create_vehicle(
        self, vehicle_id: str, name: str = "", vehicle_type: str = "usv"
    ) -> Body:
        """``{vehicle_id, token}``: the vehicle's token, shown this once."""
        body = {"vehicle_id": vehicle_id, "name": name, "vehicle_type": vehicle_type}
        answer: Body = await self.call("POST", "/api/vehicles", json=body)
        return answer

    async def update_vehicle(
        self, vehicle_id: str, *, name: str | None = None, vehicle_type: str | None = None
    ) -> Body:
        """``PATCH /api/vehicles/{vehicle_id}`` (admin): its name or type put right; the
        fleet's view of the vehicle after."""
        body = given(name=name, vehicle_type=vehicle_type)
        answer: Body = await self.call("PATCH", f"/api/vehicles/{vehicle_id}", json=body)
        return answer

    async def gateways(self) -> Body:
        """``{"gateways": [{gateway_id, vehicles, created_at, active_tokens}, ...]}`` (admin)."""
        body: Body = await self.call("GET", "/api/gateways")
        return body

    async def create_gateway(self, gateway_id: str, vehicles: OneOrMany) -> Body:
        """``{gateway_id, token, vehicles}``: the gateway's token, shown this once."""
        body = {"gateway_id": gateway_id, "vehicles": listed(vehicles)}
        answer: Body = await self.call("POST", "/api/gateways", json=body)
        return answer

    async def rotate_token(self, kind: str, subject: str) -> Body:
        """A new token for a ``vehicle``, ``gateway`` or ``user``, every former one revoked
        (the answer of ``POST /api/{kind}s/{subject}/rotate_token``)."""
        body: Body = await self.call("POST", f"/api/{_plural(kind)}/{subject}/rotate_token")
        return body

    async def revoke_tokens(self, kind: str, subject: str) -> Body:
        """Every token of a ``vehicle``, ``gateway`` or ``user`` revoked: ``{"ok": true}``."""
        body: Body = await self.call("POST", f"/api/{_plural(kind)}/{subject}/revoke_tokens")
        return body

    # ---- safety: zones, failsafes, operator liveness, the control log --------------
    async def zones(self, at: str | None = None) -> Body:
        """``{"zones": [...], "version"}``: the operating areas and no-go zones; ``at``
        (ISO 8601): as they were then."""
        body: Body = await self.call("GET", "/api/zones", params=given(at=at))
        return body

    async def create_zone(
        self,
        name: str,
        kind: str,
        polygon: Body,
        vehicles: OneOrMany = (),
        clearance_m: float | None = None,
    ) -> Body:
        """(admin) A zone: ``kind`` ``no_go`` or ``operating_area``, ``polygon`` GeoJSON."""
        fields = given(clearance_m=clearance_m)
        body: Body = await self.call(
            "POST",
            "/api/zones",
            json={"name": name, "kind": kind, "polygon": polygon, "vehicles": listed(vehicles)}
            | fields,
        )
        return body

    async def update_zone(self, zone_id: str, **changes: Any) -> Body:
        """(admin) Change any of ``name``, ``polygon``, ``vehicles``, ``clearance_m``
        (those given); the zone as it is now."""
        body: Body = await self.call("PATCH", f"/api/zones/{zone_id}", json=changes)
        return body

    async def delete_zone(self, zone_id: str) -> Body:
        body: Body = await self.call("DELETE", f"/api/zones/{zone_id}")
        return body

    async def zone_id_of(self, ref: str) -> str:
        """The id of the zone whose id or name is ``ref`` (as :func:`pick_named`)."""
        return str(pick_named(ref, (await self.zones())["zones"], "zone")["zone_id"])

    # ---- fixed obstacles (the planner keeps clear of them) ---------------------------
    async def obstacles(self, at: str | None = None) -> Body:
        """``{"obstacles": [...]}``: the known fixed obstacles; ``at`` (ISO 8601): those
        there were then (one removed since with its ``deleted_at``)."""
        body: Body = await self.call("GET", "/api/obstacles", params=given(at=at))
        return body

    async def create_obstacle(
        self, name: str, polygon: Body, clearance_m: float | None = None
    ) -> Body:
        """(admin) A fixed obstacle, ``polygon`` GeoJSON."""
        fields = given(clearance_m=clearance_m)
        body: Body = await self.call(
            "POST", "/api/obstacles", json={"name": name, "polygon": polygon} | fields
        )
        return body

    async def delete_obstacle(self, obstacle_id: str) -> Body:
        body: Body = await self.call("DELETE", f"/api/obstacles/{obstacle_id}")
        return body

    async def obstacle_id_of(self, ref: str) -> str:
        """The id of the obstacle whose id or name is ``ref``."""
        found = pick_named(ref, (await self.obstacles())["obstacles"], "obstacle")
        return str(found["obstacle_id"])

    async def dead_letters(self, loop: str | None = None, limit: int | None = None) -> Body:
        """(admin) The records a background loop set aside (``docs/storage.md``)."""
        body: Body = await self.call(
            "GET", "/api/dead_letters", params=given(loop=loop, limit=limit)
        )
        return body

    async def failsafe(self, vehicle_id: str) -> Body:
        """The vehicle's failsafe policy, and whether its instance applies it."""
        body: Body = await self.call("GET", f"/api/vehicles/{vehicle_id}/failsafe")
        return body

    async def set_failsafe(self, vehicle_id: str, **policy: Any) -> Body:
        """(manager of the vehicle, admin) The whole policy: ``action``, ``after_s``,
        ``home`` ({lat, lon}), ``on_breach``, ``low_battery_pct``."""
        body: Body = await self.call(
            "PUT", f"/api/vehicles/{vehicle_id}/failsafe", json=given(**policy)
        )
        return body


_KINDS = {"vehicle": "vehicles", "gateway": "gateways", "user": "users"}


def _plural(kind: str) -> str:
    try:
        return _KINDS[kind]
    except KeyError:
        raise ValueError(f"kind is vehicle, gateway or user, not {kind!r}") from None
