"""Authentication and accounts: tokens (SHA-256 digests), passwords (argon2), roles.

Every request looks its token up by digest; the answer is cached in process.
When a token is revoked, or its owner disabled or changed, the entry is
dropped here and :class:`~server.domain.events.TokensRevoked` goes out: the
sockets holding it close, and other replicas drop their entries too (through
the bus, within milliseconds). While that news cannot travel (the bus to the
other replicas is down), an entry is trusted for at most
:data:`UNCONFIRMED_TRUST_S` before the store is asked again, so that a
revocation takes effect everywhere within that time.

``/auth/token`` checks a password as :class:`~server.services.logins.Logins`
says (argon2, the same work for an unknown user, failed logins limited per
address and per user) and issues a session token.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import logging
import secrets
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from fleet_protocol import CreateGateway, CreateUser, CreateVehicle, PatchUser, utcnow
from server.domain.access import Principal
from server.domain.clock import Clock
from server.domain.events import TokensRevoked, UserChanged
from server.errors import Conflict, Invalid, NotFound, RateLimited, Unauthorized
from server.services.logins import Logins
from server.services.messagebus import MessageBus
from server.settings import Settings
from server.storage.accounts import AccountsRepo
from server.storage.backends import Duplicate

log = logging.getLogger("fleet.auth")
TOKEN_PREFIX = "fct_"
BOOTSTRAP_ADMIN = "admin"
#: How long a cached token is trusted while revocations from other replicas cannot arrive.
UNCONFIRMED_TRUST_S = 1.0


def digest(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


def new_token() -> str:
    return TOKEN_PREFIX + secrets.token_urlsafe(32)


@dataclass
class _Cached:
    principal: Principal
    expires_at: float | None  # wall clock seconds, None: never
    checked_at: float  # monotonic: when the store last said it was valid


class _Bucket:
    """Token-bucket rate limit per token."""

    __slots__ = ("stamp", "tokens")

    def __init__(self, burst: float) -> None:
        self.tokens = burst
        self.stamp = time.monotonic()


class AuthService:
    def __init__(
        self,
        settings: Settings,
        repo: AccountsRepo,
        messages: MessageBus,
        news_flows: Callable[[], bool] = lambda: True,
        clock: Clock = utcnow,
    ) -> None:
        self.settings = settings
        self.repo = repo
        self.messages = messages
        self.clock = clock
        #: Whether revocations made on other replicas reach this one now (the bus is up).
        self._news_flows = news_flows
        self.logins = Logins(settings, repo, clock)
        self._cache: dict[str, _Cached] = {}
        self._buckets: dict[str, _Bucket] = {}
        #: token id -> set when it is revoked, while someone waits on it (long polls).
        self._revoked: dict[str, asyncio.Event] = {}
        self._waiting: dict[str, int] = {}

    async def load(self) -> None:
        await self.repo.ensure_indexes()

    # ---- requests -------------------------------------------------------
    async def authenticate(self, token: str | None) -> Principal:
        if not token:
            raise Unauthorized("a bearer token is required")
        return await self.authenticate_digest(digest(token))

    def cached(self, key: str) -> Principal | None:
        """The principal of a token digest known valid, without a store read; else None."""
        cached = self._cache.get(key)
        if cached is None:
            return None
        if cached.expires_at is not None and cached.expires_at <= time.time():
            return None
        if time.monotonic() - cached.checked_at > UNCONFIRMED_TRUST_S and not self._news_flows():
            return None
        return cached.principal

    async def authenticate_digest(self, key: str) -> Principal:
        """:meth:`authenticate` for a token whose digest is known (a socket's every frame)."""
        principal = self.cached(key)
        if principal is not None:
            return principal
        checked_at = time.monotonic()
        principal, expires_at = await self._load(key)
        if len(self._cache) > 100_000:
            self._cache.clear()
        self._cache[key] = _Cached(principal, expires_at, checked_at)
        return principal

    async def _load(self, key: str) -> tuple[Principal, float | None]:
        doc = await self.repo.token(key)
        if doc is None or doc.get("revoked_at") is not None:
            raise Unauthorized("the token is not valid")
        expires = doc.get("expires_at")
        if expires is not None and expires <= utcnow():
            raise Unauthorized("the token has expired")
        kind, subject, token_id = doc["kind"], doc["subject"], doc["token_id"]
        if kind == "user":
            user = await self.repo.user(subject)
            if user is None or user.get("disabled"):
                raise Unauthorized("the account is disabled")
            vehicles = frozenset(user.get("vehicles", []))
            principal = Principal("user", subject, user["role"], vehicles, token_id, expires)
        elif kind == "gateway":
            gw = await self.repo.gateway(subject)
            if gw is None:
                raise Unauthorized("the gateway no longer exists")
            vehicles = frozenset(gw.get("vehicles", []))
            principal = Principal("gateway", subject, None, vehicles, token_id, expires)
        else:
            principal = Principal("vehicle", subject, None, frozenset({subject}), token_id, expires)
        return principal, expires.timestamp() if expires is not None else None

    def check_rate(self, principal: Principal) -> None:
        bucket = self._buckets.get(principal.token_id)
        burst = float(self.settings.rate_limit_burst)
        if bucket is None:
            bucket = self._buckets[principal.token_id] = _Bucket(burst)
        now = time.monotonic()
        bucket.tokens = min(
            burst, bucket.tokens + (now - bucket.stamp) * self.settings.rate_limit_per_s
        )
        bucket.stamp = now
        if bucket.tokens < 1:
            wait = (1 - bucket.tokens) / self.settings.rate_limit_per_s
            raise RateLimited("too many requests for this token", retry_after_s=max(wait, 0.1))
        bucket.tokens -= 1

    # ---- tokens ---------------------------------------------------------
    async def _issue(
        self,
        kind: str,
        subject: str,
        *,
        ttl_s: int | None = None,
        purpose: str = "api",
        token: str | None = None,
    ) -> str:
        token = token or new_token()
        now = utcnow()
        await self.repo.insert_token(
            {
                "token_id": secrets.token_hex(8),
                "digest": digest(token),
                "kind": kind,
                "subject": subject,
                "purpose": purpose,
                "created_at": now,
                "expires_at": now + timedelta(seconds=ttl_s) if ttl_s else None,
                "revoked_at": None,
            }
        )
        return token

    async def _revoke(self, flt: dict[str, Any]) -> None:
        revoked = await self.repo.revoke_tokens(flt, utcnow())
        self._forget({doc["digest"] for doc in revoked}, {doc["token_id"] for doc in revoked})

    def _forget(self, digests: set[str], token_ids: set[str]) -> None:
        self.forget(frozenset(digests), frozenset(token_ids))
        if digests or token_ids:
            self.messages.emit_now(TokensRevoked(frozenset(token_ids), frozenset(digests)))

    def forget(self, digests: frozenset[str], token_ids: frozenset[str] = frozenset()) -> None:
        """These tokens were revoked (here or on another replica): drop them from the
        cache, and end what waits on them (:meth:`until_invalid`)."""
        for key in digests:
            self._cache.pop(key, None)
        for token_id in token_ids:
            if (waiting := self._revoked.get(token_id)) is not None:
                waiting.set()

    async def until_invalid(self, principal: Principal) -> None:
        """Return when ``principal``'s token is revoked or expires (a long poll ends then)."""
        token_id = principal.token_id
        event = self._revoked.setdefault(token_id, asyncio.Event())
        self._waiting[token_id] = self._waiting.get(token_id, 0) + 1
        timeout = None
        if principal.expires_at is not None:
            timeout = max(0.0, (principal.expires_at - utcnow()).total_seconds())
        try:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(event.wait(), timeout)
        finally:
            self._waiting[token_id] -= 1
            if not self._waiting[token_id]:
                del self._waiting[token_id]
                self._revoked.pop(token_id, None)

    def forget_all(self) -> None:
        """Revocations may have been missed (the bus was down): ask the store again."""
        self._cache.clear()

    async def _forget_subject(self, kind: str, subject: str) -> None:
        """The subject changed (role, vehicles, disabled): every replica reads its tokens
        again, and the sockets that hold them close (they reconnect with the new rights)."""
        docs = await self.repo.tokens_of(kind, subject)
        self._forget({d["digest"] for d in docs}, {d["token_id"] for d in docs})

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
        :class:`~server.domain.events.UserChanged` (leases the user may no longer hold end)."""
        await self.get_user(username)
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
        await self._forget_subject("user", username)
        if body.role is not None or body.vehicles is not None or body.disabled is not None:
            await self.messages.emit(UserChanged(username, actor))
        return await self.get_user(username)

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
