"""Users, vehicles, gateways and API tokens (as digests)."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from server.storage.driver import Doc, Store


class AccountsRepo:
    def __init__(self, store: Store) -> None:
        self.users = store["users"]
        self.tokens = store["tokens"]
        self.vehicles = store["vehicles"]
        self.gateways = store["gateways"]

    async def ensure_indexes(self) -> None:
        # Small collections: lookups by key; no unique index (see ARCHITECTURE.md).
        await self.tokens.create_index([("digest", 1)])
        await self.users.create_index([("username", 1)])
        await self.vehicles.create_index([("vehicle_id", 1)])

    # users
    async def user(self, username: str) -> Doc | None:
        return await self.users.find_one({"username": username})

    async def all_users(self) -> list[Doc]:
        return await self.users.find({}, sort=[("username", 1)], projection={"password_hash": 0})

    async def insert_user(self, doc: Doc) -> None:
        await self.users.insert_one(doc)

    async def update_user(self, username: str, fields: dict[str, Any]) -> None:
        await self.users.update_one({"username": username}, {"$set": fields})

    # vehicles and gateways
    async def vehicle(self, vehicle_id: str) -> Doc | None:
        return await self.vehicles.find_one({"vehicle_id": vehicle_id})

    async def all_vehicles(self) -> list[Doc]:
        return await self.vehicles.find({}, sort=[("vehicle_id", 1)])

    async def upsert_vehicle(self, vehicle_id: str, fields: dict[str, Any]) -> None:
        await self.vehicles.update_one({"vehicle_id": vehicle_id}, {"$set": fields}, upsert=True)

    async def gateway(self, gateway_id: str) -> Doc | None:
        return await self.gateways.find_one({"gateway_id": gateway_id})

    async def upsert_gateway(self, gateway_id: str, fields: dict[str, Any]) -> None:
        await self.gateways.update_one({"gateway_id": gateway_id}, {"$set": fields}, upsert=True)

    # tokens
    async def token(self, digest: str) -> Doc | None:
        return await self.tokens.find_one({"digest": digest})

    async def insert_token(self, doc: Doc) -> None:
        await self.tokens.insert_one(doc)

    async def revoke_tokens(self, flt: dict[str, Any], at: datetime) -> list[Doc]:
        """Revoke the live tokens matching ``flt``; returns them (as they were)."""
        live = await self.tokens.find({**flt, "revoked_at": None})
        for doc in live:
            await self.tokens.update_one(
                {"token_id": doc["token_id"]}, {"$set": {"revoked_at": at}}
            )
        return live

    async def drop_expired_tokens(self, before: datetime) -> int:
        return await self.tokens.delete_many({"expires_at": {"$lt": before}})
