"""Known fixed obstacles: one small document each, keyed by ``obstacle_id``."""

from __future__ import annotations

from server.storage.backends import Doc, Store


class ObstaclesRepo:
    def __init__(self, store: Store) -> None:
        self.obstacles = store["obstacles"]

    async def all(self) -> list[Doc]:
        return await self.obstacles.find({}, sort=[("created_at", 1), ("_id", 1)])

    async def get(self, obstacle_id: str) -> Doc | None:
        return await self.obstacles.get(obstacle_id)

    async def count(self) -> int:
        return await self.obstacles.count({})

    async def insert(self, doc: Doc) -> None:
        await self.obstacles.insert({**doc, "_id": doc["obstacle_id"]})

    async def delete(self, obstacle_id: str) -> bool:
        return await self.obstacles.delete({"_id": obstacle_id}) > 0
