"""Passwords and failed logins.

A password is kept as its argon2 hash, and checked in a worker thread. An
unknown user, or one without a password, is answered after the same argon2
work as a known one (against a dummy hash). Failed attempts are counted per
client address and per username in the store (every replica counts the same
ones): past ``FLEET_LOGIN_FAILURES_PER_ADDRESS`` or
``FLEET_LOGIN_FAILURES_PER_USER`` within ``FLEET_LOGIN_WINDOW_S`` a login is
429 ``rate_limited`` with ``Retry-After``, without looking at the password.
"""

from __future__ import annotations

import asyncio
import hashlib
import ipaddress
import math
import secrets
from datetime import datetime, timedelta
from typing import Any

from argon2 import PasswordHasher
from argon2.exceptions import InvalidHashError, VerificationError

from server.domain.clock import Clock
from server.errors import RateLimited, Unauthorized
from server.settings import Settings
from server.storage.accounts import AccountsRepo
from server.storage.backends import Doc

__all__ = ["Logins", "client_key"]


def client_key(host: str | None) -> str:
    """What failed logins are counted by for a client address: the address itself, an
    IPv6 one by its /64 (one subscriber's share: it has them all), an IPv4 one mapped in
    IPv6 as IPv4."""
    if not host:
        return "unknown"
    try:
        addr = ipaddress.ip_address(host)
    except ValueError:
        return host[:64]
    if isinstance(addr, ipaddress.IPv6Address):
        if addr.ipv4_mapped is not None:
            return str(addr.ipv4_mapped)
        return str(ipaddress.IPv6Network((addr, 64), strict=False))
    return str(addr)


class Logins:
    def __init__(self, settings: Settings, repo: AccountsRepo, clock: Clock) -> None:
        self.settings = settings
        self.repo = repo
        self.clock = clock
        self._hasher = PasswordHasher()
        #: What an unknown user's password is checked against (made once, on first use).
        self._dummy_hash: str | None = None

    async def hash(self, password: str) -> str:
        return await asyncio.to_thread(self._hasher.hash, password)

    async def check(self, username: str, password: str, address: str | None) -> Doc:
        """The user, for a right password; 401 otherwise, after the same work whether the
        user exists or not; 429 past the failed-login limits.

        The attempt is recorded before the password is checked and counted again after,
        so that a burst of attempts at once gets no more checks than the limit; a
        successful one is deleted (only failures count), a refused one too.
        """
        now = self.clock()
        attempt: dict[str, Any] = {
            "attempt_id": secrets.token_hex(12),
            "address": client_key(address),
            # What was typed as a username is kept as a digest: a token or a password
            # pasted into that field never reaches the store in clear.
            "user": "sha256:" + hashlib.sha256(username.encode()).hexdigest(),
            "at": now,
        }
        await self._check_limits(attempt, now, recorded=False)
        await self.repo.insert_login_attempt(attempt)
        try:
            await self._check_limits(attempt, now, recorded=True)
        except RateLimited:
            await self.repo.drop_login_attempt(attempt["attempt_id"])
            raise
        user = await self.repo.user(username)
        ok = await self._password_matches((user or {}).get("password_hash"), password)
        if not ok or user is None or user.get("disabled"):
            raise Unauthorized("wrong username or password")  # the attempt stays: a failure
        await self.repo.drop_login_attempt(attempt["attempt_id"])
        return user

    async def _password_matches(self, stored: str | None, password: str) -> bool:
        """argon2 verification, against a dummy hash when there is no stored one (unknown
        user, user without a password): the answer takes as long either way."""
        if not stored:
            if self._dummy_hash is None:
                self._dummy_hash = await self.hash(secrets.token_urlsafe(32))
            await self._verify(self._dummy_hash, password)
            return False  # whatever was sent
        return await self._verify(stored, password)

    async def _verify(self, stored: str, password: str) -> bool:
        try:
            return bool(await asyncio.to_thread(self._hasher.verify, stored, password))
        except (VerificationError, InvalidHashError):
            return False

    async def _check_limits(
        self, attempt: dict[str, Any], now: datetime, *, recorded: bool
    ) -> None:
        """429 when the attempt's address or user is past its limit of failures in the
        window (``recorded``: the attempt itself is among those counted)."""
        since = now - timedelta(seconds=self.settings.login_window_s)
        limits = (
            ("address", self.settings.login_failures_per_address, "from this address"),
            ("user", self.settings.login_failures_per_user, "for this user"),
        )
        for field, limit, whose in limits:
            count = await self.repo.count_login_attempts(field, attempt[field], since)
            if recorded:
                count -= 1  # the others, this one aside
            if count < limit:
                continue
            # Free again once enough of the oldest leave the window for one more attempt.
            oldest = await self.repo.login_attempts_of(
                field, attempt[field], since, count - limit + 1
            )
            free_at = oldest[-1]["at"] + timedelta(seconds=self.settings.login_window_s)
            wait = max(1, math.ceil((free_at - now).total_seconds()))
            raise RateLimited(
                f"too many failed logins {whose}; try again in {wait} s",
                retry_after_s=wait,
                details={"limit": field, "retry_after_s": wait},
            )

    async def drop_old_attempts(self, now: datetime) -> int:
        """Forget the attempts older than the window (the retention loop)."""
        return await self.repo.drop_login_attempts_before(
            now - timedelta(seconds=self.settings.login_window_s)
        )
