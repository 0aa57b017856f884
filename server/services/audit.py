"""The tamper-evident control log: grants, leases and commands of each vehicle in one
append-only chain, each entry carrying the hash of the one before it
(:mod:`fleet_protocol.audit`).

Entries come from the events the services record (kinds in :data:`AUDITED`) and from
each step of a command (``CommandMoved``), on the replica where they happened. Appends
for one vehicle go one at a time here (a lock per vehicle, taken in the order the
events came) and by key in the store across replicas: the ``seq`` after the last
entry, or, when another replica took it first, the one after that.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Awaitable
from typing import Any

from fleet_protocol import GENESIS, entry_hash, format_ts
from server.domain.clock import Clock
from server.domain.events import CommandMoved, EventRecorded
from server.services.dead_letters import DeadLetters
from server.storage.audit import AuditRepo
from server.storage.backends import Doc

#: The event kinds the control log keeps: who asked for control and was refused or given
#: it, who lost it and why,
#: every command's life, the failsafe each vehicle was set to and when it acted.
AUDITED = frozenset(
    {
        "control_request",
        "control_deny",
        "control_grant",
        "control_revoke",
        "control_release",
        "control_expired",
        "hold_station",
        "command",
        "failsafe_changed",
        "failsafe_entered",
        "failsafe_left",
    }
)
#: Tries to append while other replicas append to the same vehicle's chain.
_TRIES = 20
#: An audit page holds this many entries at most.
MAX_PAGE = 1000


class AuditLog:
    def __init__(self, repo: AuditRepo, dead_letters: DeadLetters, clock: Clock) -> None:
        self.repo = repo
        self.dead_letters = dead_letters
        self.clock = clock
        self._locks: dict[str, asyncio.Lock] = {}

    async def load(self) -> None:
        await self.repo.ensure_indexes()

    def on_event(self, event: EventRecorded) -> Awaitable[None] | None:
        doc = event.doc
        if doc["kind"] not in AUDITED or not doc.get("vehicle_id"):
            return None
        data = {**doc.get("data", {}), "instance_id": doc.get("instance_id")}
        return self._append(doc["vehicle_id"], doc["kind"], doc.get("actor"), data)

    def on_command_moved(self, event: CommandMoved) -> Awaitable[None]:
        data = {
            "command_id": event.command_id,
            "type": event.type,
            "status": event.status,
            "detail": event.detail,
        }
        return self._append(event.vehicle_id, "command", None, data)

    def _append(
        self, vehicle_id: str, kind: str, actor: str | None, data: dict[str, Any]
    ) -> Awaitable[None]:
        lock = self._locks.setdefault(vehicle_id, asyncio.Lock())
        entry = {
            "vehicle_id": vehicle_id,
            "at": format_ts(self.clock()),
            "kind": kind,
            "actor": actor,
            "data": json.loads(json.dumps(data, default=str)),  # as the wire will show it
        }
        return self._write(lock, entry)

    async def _write(self, lock: asyncio.Lock, entry: dict[str, Any]) -> None:
        async with lock:
            try:
                for _ in range(_TRIES):
                    last = await self.repo.last(entry["vehicle_id"])
                    prev = last["hash"] if last else GENESIS
                    doc = {**entry, "seq": (int(last["seq"]) if last else 0) + 1}
                    doc["prev_hash"] = prev
                    doc["hash"] = entry_hash(prev, doc)
                    if await self.repo.append(doc):
                        return
                raise RuntimeError("the chain keeps moving")
            except Exception as exc:
                await self.dead_letters.set_aside("audit", entry["vehicle_id"], exc, entry)

    async def page(
        self, vehicle_id: str, after_seq: int, limit: int
    ) -> tuple[list[Doc], int | None]:
        docs = await self.repo.page(vehicle_id, after_seq, min(limit, MAX_PAGE))
        for d in docs:
            d.pop("_id", None)
        more = docs[-1]["seq"] if len(docs) == min(limit, MAX_PAGE) else None
        return docs, more
