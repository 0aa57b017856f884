"""Tokens: who a request is (a SHA-256 digest looked up, cached), its rate, revocation.

Every request looks its token up by digest; the answer is cached in process.
When a token is revoked, or its owner disabled or changed, the entry is
dropped here and :class:`~server.domain.events.TokensRevoked` goes out: the
sockets holding it close, and other replicas drop their entries too (through
the bus, within milliseconds). While that news cannot travel (the bus to the
other replicas is down), an entry is trusted for at most
:data:`UNCONFIRMED_TRUST_S` before the store is asked again, so that a
revocation takes effect everywhere within that time. The accounts the tokens
belong to are :class:`~server.services.auth.AuthService`'s.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import secrets
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import timedelta
from typing import Any

from fleet_protocol import utcnow
from server.domain.access import Principal
from server.domain.clock import Clock
from server.domain.events import TokensRevoked
from server.errors import RateLimited, Unauthorized
from server.services.messagebus import MessageBus
from server.settings import Settings
from server.storage.accounts import AccountsRepo

TOKEN_PREFIX = "fct_"
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


class Tokens:
    """The tokens' side of :class:`~server.services.auth.AuthService` (its base)."""

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
        self._cache: dict[str, _Cached] = {}
        self._buckets: dict[str, _Bucket] = {}
        #: token id -> set when it is revoked, while someone waits on it (long polls).
        self._revoked: dict[str, asyncio.Event] = {}
        self._waiting: dict[str, int] = {}

    # ---- requests -------------------------------------------------------
    async def authenticate(self, token: str | None) -> Principal:
        if not token:
            raise Unauthorized("a bearer token is required")
        return await self.authenticate_digest(digest(token))

    def known(self, token: str | None) -> Principal | None:
        """The principal of a token known valid, without a store read (and without a
        coroutine: the vehicles' every call); None: :meth:`authenticate` decides."""
        return self.cached(digest(token)) if token else None

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

    async def _revoke(self, flt: dict[str, Any]) -> int:
        """Revoke the tokens ``flt`` matches; how many."""
        revoked = await self.repo.revoke_tokens(flt, utcnow())
        self._forget({doc["digest"] for doc in revoked}, {doc["token_id"] for doc in revoked})
        return len(revoked)

    def _forget(self, digests: set[str], token_ids: set[str], *, revoked: bool = True) -> None:
        self.forget(frozenset(digests), frozenset(token_ids))
        if digests or token_ids:
            self.messages.emit_now(
                TokensRevoked(frozenset(token_ids), frozenset(digests), revoked=revoked)
            )

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

    async def _forget_subject(self, kind: str, subject: str, *, refused: bool = False) -> None:
        """The subject changed (role, vehicles, disabled): every replica reads its tokens
        again, and the sockets that hold them close: to reconnect with the new rights, or,
        ``refused`` (a user disabled), as for a revoked token (4401)."""
        docs = await self.repo.tokens_of(kind, subject)
        self._forget({d["digest"] for d in docs}, {d["token_id"] for d in docs}, revoked=refused)
