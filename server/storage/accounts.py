"""Users, vehicles, gateways and API tokens (as digests).

Each document's ``_id`` is its key (username, vehicle id, gateway id, token
digest), so a lookup is a keyed read and a second insert of one key is
refused by the store itself (two replicas starting at once make one admin).

``login_attempts`` holds one document per ``/auth/token`` attempt under way
or failed (``{address, user, at}``; a successful one is deleted), counted by
address and by user over a sliding window, and dropped once older than it.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from server.storage.backends import Doc, Store


class AccountsRepo:
    def __init__(self, store: Store) -> None:
        self.users = store["users"]
        self.tokens = store["tokens"]
        self.vehicles = store["vehicles"]
        self.gateways = store["gateways"]
        self.login_attempts = store["login_attempts"]

    async def ensure_indexes(self) -> None:
        await self.tokens.create_index([("subject", 1), ("kind", 1)])
        await self.tokens.create_index([("expires_at", 1)])
        await self.login_attempts.create_index([("address", 1), ("at", 1)])
        await self.login_attempts.create_index([("user", 1), ("at", 1)])
        await self.login_attempts.create_index([("at", 1)])

    # users
    async def user(self, username: str) -> Doc | None:
        return await self.users.get(username)

    async def all_users(self) -> list[Doc]:
        return await self.users.find({}, sort=[("_id", 1)], projection={"password_hash": 0})

    async def insert_user(self, doc: Doc) -> None:
        """:class:`~server.storage.Duplicate` when the username is taken."""
        await self.users.insert({**doc, "_id": doc["username"]})

    async def update_user(self, username: str, fields: dict[str, Any]) -> None:
        await self.users.update({"_id": username}, set=fields)

    # vehicles and gateways
    async def vehicle(self, vehicle_id: str) -> Doc | None:
        return await self.vehicles.get(vehicle_id)

    async def all_vehicles(self) -> list[Doc]:
        return await self.vehicles.find({}, sort=[("_id", 1)])

    async def insert_vehicle(self, doc: Doc) -> None:
        await self.vehicles.insert({**doc, "_id": doc["vehicle_id"]})

    async def update_vehicle(self, vehicle_id: str, fields: Doc) -> None:
        await self.vehicles.update({"_id": vehicle_id}, set=fields)

    async def gateway(self, gateway_id: str) -> Doc | None:
        return await self.gateways.get(gateway_id)

    async def all_gateways(self) -> list[Doc]:
        return await self.gateways.find({}, sort=[("_id", 1)])

    async def insert_gateway(self, doc: Doc) -> None:
        await self.gateways.insert({**doc, "_id": doc["gateway_id"]})

    # tokens
    async def token(self, digest: str) -> Doc | None:
        return await self.tokens.get(digest)

    async def insert_token(self, doc: Doc) -> None:
        await self.tokens.insert({**doc, "_id": doc["digest"]})

    async def tokens_of(self, kind: str, subject: str) -> list[Doc]:
        return await self.tokens.find({"subject": subject, "kind": kind})

    async def revoke_tokens(self, flt: dict[str, Any], at: datetime) -> list[Doc]:
        """Revoke the live tokens matching ``flt``; returns them (as they were)."""
        live = await self.tokens.find({**flt, "revoked_at": None})
        for doc in live:
            await self.tokens.update({"_id": doc["_id"]}, set={"revoked_at": at})
        return live

    async def reinstate_token(self, digest: str, username: str) -> None:
        await self.tokens.update(
            {"_id": digest},
            set={"revoked_at": None, "kind": "user", "subject": username, "expires_at": None},
        )

    async def drop_expired_tokens(self, before: datetime) -> int:
        return await self.tokens.delete({"expires_at": {"$lt": before}})

    # login attempts
    async def insert_login_attempt(self, doc: Doc) -> None:
        await self.login_attempts.insert({**doc, "_id": doc["attempt_id"]})

    async def drop_login_attempt(self, attempt_id: str) -> None:
        await self.login_attempts.delete({"_id": attempt_id})

    async def count_login_attempts(self, field: str, value: str, since: datetime) -> int:
        """Attempts of this ``address`` or ``user`` later than ``since``."""
        return await self.login_attempts.count({field: value, "at": {"$gt": since}})

    async def login_attempts_of(
        self, field: str, value: str, since: datetime, limit: int
    ) -> list[Doc]:
        """The oldest ``limit`` attempts of this ``address`` or ``user`` later than ``since``."""
        return await self.login_attempts.find(
            {field: value, "at": {"$gt": since}}, sort=[("at", 1)], limit=limit
        )

    async def drop_login_attempts_before(self, before: datetime) -> int:
        return await self.login_attempts.delete({"at": {"$lte": before}})
