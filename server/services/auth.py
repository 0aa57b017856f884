"""Accounts: the admin, users (passwords with argon2, roles), vehicles and gateways.

:class:`AuthService` is the tokens' service (:class:`~server.services.tokens.Tokens`:
who a request is, its rate, revocation) and the accounts' one: the bootstrap
admin, ``/auth/token`` (a password checked as :class:`~server.services.logins.Logins`
says: argon2, the same work for an unknown user, failed logins limited per
address and per user), and the administration of users, vehicles and gateways,
whose tokens it issues and revokes.
"""

from __future__ import annotations

import contextlib
import functools
import logging
from collections.abc import Mapping
from datetime import datetime
from typing import Any

from fleet_protocol import CreateGateway, CreateUser, CreateVehicle, PatchUser, utcnow
from server.domain.access import Principal, enabled_admin, unseats_admin
from server.domain.events import UserChanged
from server.errors import Conflict, Invalid, NotFound
from server.services.logins import Logins
from server.services.tokens import Tokens, digest
from server.storage.backends import Duplicate

BOOTSTRAP_ADMIN = "admin"

log = logging.getLogger("fleet.auth")


class AuthService(Tokens):
    """Built as :class:`Tokens` is (the same arguments); :attr:`logins` made from them."""

    @functools.cached_property
    def logins(self) -> Logins:
        return Logins(self.settings, self.repo, self.clock)

    async def load(self) -> None:
        await self.repo.ensure_indexes()

    async def bootstrap_admin(self) -> str | None:
        """Make sure an admin exists. Returns a token to print, or None when it came from
        ``FLEET_ADMIN_TOKEN`` (the operator already knows it)."""
        if await self.repo.user(BOOTSTRAP_ADMIN) is None:
            with contextlib.suppress(Duplicate):  # another replica, starting at the same moment
                await self.repo.insert_user(
                    {
                        "username": BOOTSTRAP_ADMIN,
                        "role": "admin",
                        "vehicles": [],
                        "disabled": False,
                        "password_hash": None,
                        "created_at": utcnow(),
                    }
                )
        await self._keep_an_admin()
        given = self.settings.admin_token
        if given is not None:
            token = given.get_secret_value()
            doc = await self.repo.token(digest(token))
            if doc is None:
                with contextlib.suppress(Duplicate):  # made by another replica just now
                    await self._issue("user", BOOTSTRAP_ADMIN, purpose="bootstrap-env", token=token)
            elif doc.get("revoked_at") is not None or doc["subject"] != BOOTSTRAP_ADMIN:
                # The operator set this token for the admin: it is the admin's again.
                await self.repo.reinstate_token(doc["digest"], BOOTSTRAP_ADMIN)
            return None
        # No token given: each start revokes the former printed one and prints a new one.
        await self._revoke({"subject": BOOTSTRAP_ADMIN, "purpose": "bootstrap"})
        return await self._issue("user", BOOTSTRAP_ADMIN, purpose="bootstrap")

    async def _keep_an_admin(self) -> None:
        """With no enabled admin left (a store from an older version let the last one be
        demoted or disabled), the bootstrap admin is an enabled admin again."""
        if any(enabled_admin(user) for user in await self.repo.all_users()):
            return
        await self.repo.update_user(BOOTSTRAP_ADMIN, {"role": "admin", "disabled": False})
        log.warning("no enabled admin was left: %r is one again", BOOTSTRAP_ADMIN)

    # ---- login --------------------------------------------------------
    async def login(self, username: str, password: str, address: str | None) -> tuple[str, int]:
        """A session token for a right password (:meth:`Logins.check`)."""
        await self.logins.check(username, password, address)
        ttl = self.settings.token_ttl_s
        return await self._issue("user", username, ttl_s=ttl, purpose="session"), ttl

    async def drop_old_login_attempts(self, now: datetime) -> int:
        """Forget the attempts older than the window (the retention loop)."""
        return await self.logins.drop_old_attempts(now)

    # ---- administration -------------------------------------------------
    async def create_vehicle(self, body: CreateVehicle) -> str:
        try:
            await self.repo.insert_vehicle(
                {
                    "vehicle_id": body.vehicle_id,
                    "name": body.name or body.vehicle_id,
                    "vehicle_type": body.vehicle_type,
                    "created_at": utcnow(),
                },
            )
        except Duplicate:
            raise Conflict(f"vehicle {body.vehicle_id} exists already", code="exists") from None
        return await self._issue("vehicle", body.vehicle_id)

    async def change_vehicle(self, vehicle_id: str, fields: dict[str, Any]) -> dict[str, Any]:
        """Change a registered vehicle's ``name`` or ``vehicle_type``; its record as it
        was (NotFound: no such vehicle)."""
        former = await self.repo.vehicle(vehicle_id)
        if former is None:
            raise NotFound(f"no vehicle {vehicle_id}")
        if fields:
            await self.repo.update_vehicle(vehicle_id, fields)
        return former

    async def rotate_vehicle_token(self, vehicle_id: str) -> str:
        await self.revoke_vehicle_tokens(vehicle_id)
        return await self._issue("vehicle", vehicle_id)

    async def revoke_vehicle_tokens(self, vehicle_id: str) -> None:
        if await self.repo.vehicle(vehicle_id) is None:
            raise NotFound(f"no vehicle {vehicle_id}")
        await self._revoke({"kind": "vehicle", "subject": vehicle_id})

    async def get_gateway(self, gateway_id: str) -> dict[str, Any]:
        gateway = await self.repo.gateway(gateway_id)
        if gateway is None:
            raise NotFound(f"no gateway {gateway_id}")
        return gateway

    async def list_gateways(self) -> list[dict[str, Any]]:
        """Every gateway, with ``active_tokens``: how many of its tokens work now."""
        now = utcnow()
        gateways = await self.repo.all_gateways()
        for gateway in gateways:
            tokens = await self.repo.tokens_of("gateway", gateway["gateway_id"])
            gateway["active_tokens"] = sum(
                1
                for t in tokens
                if t.get("revoked_at") is None
                and (t.get("expires_at") is None or t["expires_at"] > now)
            )
        return gateways

    async def rotate_gateway_token(self, gateway_id: str) -> str:
        await self.revoke_gateway_tokens(gateway_id)
        return await self._issue("gateway", gateway_id)

    async def revoke_gateway_tokens(self, gateway_id: str) -> None:
        await self.get_gateway(gateway_id)
        await self._revoke({"kind": "gateway", "subject": gateway_id})

    async def create_gateway(self, body: CreateGateway) -> str:
        await self._require_vehicles(body.vehicles)
        try:
            await self.repo.insert_gateway(
                {
                    "gateway_id": body.gateway_id,
                    "vehicles": sorted(set(body.vehicles)),
                    "created_at": utcnow(),
                },
            )
        except Duplicate:
            raise Conflict(f"gateway {body.gateway_id} exists already", code="exists") from None
        return await self._issue("gateway", body.gateway_id)

    async def _require_vehicles(self, vehicles: list[str]) -> None:
        known = {d["vehicle_id"] for d in await self.repo.all_vehicles()}
        missing = sorted(set(vehicles) - known)
        if missing:
            raise Invalid(
                "unknown vehicles",
                details=[{"field": "vehicles", "message": f"no vehicle {v}"} for v in missing],
            )

    async def create_user(self, body: CreateUser) -> str:
        if await self.repo.user(body.username) is not None:
            raise Conflict(f"user {body.username} exists already", code="exists")
        await self._require_vehicles(body.vehicles)
        try:
            await self.repo.insert_user(
                {
                    "username": body.username,
                    "role": body.role,
                    "vehicles": sorted(set(body.vehicles)),
                    "disabled": False,
                    "password_hash": await self._hash(body.password),
                    "created_at": utcnow(),
                }
            )
        except Duplicate:
            raise Conflict(f"user {body.username} exists already", code="exists") from None
        return await self._issue("user", body.username)

    async def _hash(self, password: str | None) -> str | None:
        return None if password is None else await self.logins.hash(password)

    async def list_users(self) -> list[dict[str, Any]]:
        return await self.repo.all_users()

    async def get_user(self, username: str) -> dict[str, Any]:
        user = await self.repo.user(username)
        if user is None:
            raise NotFound(f"no user {username}")
        return user

    async def patch_user(
        self, username: str, body: PatchUser, actor: Principal | None = None
    ) -> dict[str, Any]:
        """Change a user. A new password, or disabling, ends the user's sessions (tokens
        from ``/auth/token``) but the one ``actor`` made this call with; the API token
        stays. A change of role, vehicles or ``disabled`` goes out as
        :class:`~server.domain.events.UserChanged` (leases the user may no longer hold end,
        sockets close); a patch that sets them to what they are changes nothing."""
        user = await self.get_user(username)
        if unseats_admin(user, body.role, body.disabled) and not await self._other_admin(username):
            raise Conflict(
                f"{username} is the last enabled admin: make another user admin first",
                code="last_admin",
            )
        fields: dict[str, Any] = body.model_dump(exclude_none=True, exclude={"password"})
        if body.vehicles is not None:
            await self._require_vehicles(body.vehicles)
            fields["vehicles"] = sorted(set(body.vehicles))
        if body.password is not None:
            fields["password_hash"] = await self._hash(body.password)
        if fields:
            await self.repo.update_user(username, fields)
        if body.password is not None or body.disabled:
            await self._end_sessions(username, keep=actor)
        if _rights_changed(user, body):
            await self._forget_subject("user", username, refused=bool(body.disabled))
            await self.messages.emit(UserChanged(username, actor))
        return await self.get_user(username)

    async def _other_admin(self, username: str) -> bool:
        return any(
            enabled_admin(user) and user["username"] != username
            for user in await self.repo.all_users()
        )

    async def log_out(self, principal: Principal) -> bool:
        """End the caller's token if it is a login's session token (an API token, the
        admin's first, stays: logging out of a console forgets it there, no more)."""
        if principal.kind != "user":
            return False
        return await self._revoke({"token_id": principal.token_id, "purpose": "session"}) > 0

    async def _end_sessions(self, username: str, keep: Principal | None) -> None:
        """Revoke the user's session tokens, but the one ``keep`` holds if it is theirs."""
        flt: dict[str, Any] = {"kind": "user", "subject": username, "purpose": "session"}
        if keep is not None and keep.kind == "user" and keep.name == username:
            flt["token_id"] = {"$ne": keep.token_id}
        await self._revoke(flt)

    async def revoke_user_tokens(self, username: str) -> None:
        await self.get_user(username)
        await self._revoke({"kind": "user", "subject": username})

    async def rotate_user_token(self, username: str) -> str:
        await self.revoke_user_tokens(username)
        return await self._issue("user", username)

    async def vehicle_meta(self, vehicle_id: str) -> dict[str, Any] | None:
        return await self.repo.vehicle(vehicle_id)

    async def all_vehicle_meta(self) -> list[dict[str, Any]]:
        return await self.repo.all_vehicles()

    async def user_rights(self, username: str) -> tuple[str, frozenset[str], bool] | None:
        """``(role, vehicles, disabled)`` of a user; None when there is no such user."""
        user = await self.repo.user(username)
        if user is None:
            return None
        return user["role"], frozenset(user.get("vehicles", [])), bool(user.get("disabled"))

    async def gateway_vehicles(self, gateway_ids: set[str]) -> dict[str, frozenset[str]]:
        """The vehicles each of these gateways lists (an unknown gateway: none)."""
        out: dict[str, frozenset[str]] = {}
        for gateway_id in gateway_ids:
            doc = await self.repo.gateway(gateway_id)
            out[gateway_id] = frozenset(doc.get("vehicles", [])) if doc else frozenset()
        return out

    async def user_access(self, username: str) -> tuple[str, frozenset[str]] | None:
        user = await self.repo.user(username)
        if user is None or user.get("disabled"):
            return None
        return user["role"], frozenset(user.get("vehicles", []))


def _rights_changed(user: Mapping[str, Any], body: PatchUser) -> bool:
    """Whether ``body`` changes the user's role, vehicles or ``disabled`` as stored."""
    return (
        (body.role is not None and body.role != user.get("role"))
        or (
            body.vehicles is not None
            and sorted(set(body.vehicles)) != sorted(set(user.get("vehicles", [])))
        )
        or (body.disabled is not None and body.disabled != bool(user.get("disabled")))
    )
