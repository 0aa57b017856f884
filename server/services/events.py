"""Events and audit: who did what, when. Presence changes, grants, commands, failsafes."""

from __future__ import annotations

import secrets
from datetime import datetime, timedelta
from typing import Any

from fleet_protocol import EventKind
from server.domain.access import Principal
from server.domain.clock import Clock
from server.domain.events import EventRecorded
from server.domain.windows import after_cursor, ordered, page_cursor
from server.services.messagebus import MessageBus
from server.storage.events import EventsRepo

MAX_EVENTS_PER_QUERY = 10_000


#: The kinds of event every mission makes many of (a command's submission and end, the
#: vehicle's mode changes, its instance, an admin's edits of it or of zones): those a
#: view of what happened to control and safety can do without.
ROUTINE_KINDS = ("command", "control_mode", "instance", "vehicle_changed", "zones_changed")


class EventService:
    def __init__(self, repo: EventsRepo, messages: MessageBus, clock: Clock) -> None:
        self.repo = repo
        self.messages = messages
        self.clock = clock

    async def load(self) -> None:
        await self.repo.ensure_indexes()

    async def record(
        self,
        kind: EventKind,
        *,
        vehicle_id: str | None = None,
        instance_id: str | None = None,
        actor: Principal | str | None = None,
        data: dict[str, Any] | None = None,
    ) -> dict[str, Any]:
        doc = {
            "event_id": secrets.token_hex(8),
            "kind": kind,
            "vehicle_id": vehicle_id,
            "instance_id": instance_id,
            "at": self.clock(),
            "actor": actor.label() if isinstance(actor, Principal) else actor,
            "data": data or {},
        }
        await self.repo.insert(doc)
        doc.pop("_id", None)
        self.messages.emit_now(EventRecorded(doc))
        return doc

    async def query(
        self,
        principal: Principal,
        *,
        vehicle_id: str | None,
        kind: EventKind | None,
        start: datetime | None,
        end: datetime | None,
        limit: int,
        after: str | None = None,
    ) -> dict[str, Any]:
        """A page of the log: ``events`` oldest first, ``cursor`` the last one's (None:
        no event), ``next_after`` that cursor when the page is full (there may be more),
        else None. ``after``: a cursor of a page before; without ``from`` the window then
        starts at its event, not a day back."""
        ordered(start, end)
        past = after_cursor(after) if after is not None else None
        # A ``from`` still to come, with no ``to``, finds nothing (a client following
        # the log from its own clock, a little ahead of the server's, is not refused).
        end = end or self.clock() + timedelta(seconds=1)
        start = start or (past[0] if past is not None else end - timedelta(days=1))
        if vehicle_id is not None:
            vehicle_ids: list[str] | None = [vehicle_id]
        elif principal.is_admin:
            vehicle_ids = None
        else:
            vehicle_ids = sorted(principal.vehicles)
        if vehicle_ids == []:
            return {"events": [], "cursor": None, "next_after": None}
        limit = min(limit, MAX_EVENTS_PER_QUERY)
        docs = await self.repo.query(
            vehicle_ids=vehicle_ids, kind=kind, start=start, end=end, limit=limit, after=past
        )
        cursor = page_cursor(docs[-1]["at"], str(docs[-1]["_id"])) if docs else None
        for doc in docs:
            del doc["_id"]
        return {
            "events": docs,
            "cursor": cursor,
            "next_after": cursor if len(docs) == limit else None,
        }

    async def latest(self, vehicle_id: str, count: int) -> list[dict[str, Any]]:
        """The vehicle's last ``count`` events of the last day, oldest first (the caller
        has checked that it sees the vehicle); and its last ``count`` of the day that are
        not routine (:data:`ROUTINE_KINDS`; a stop is not), which a run of commands and
        mode changes would otherwise push out: a console opened later lists what happened
        to control and safety (a revoke, a lapse, a boat gone offline) without a gap."""
        since = self.clock() - timedelta(days=1)
        every = await self.repo.latest(vehicle_id, count)
        notable = await self.repo.latest(vehicle_id, count, besides=ROUTINE_KINDS)
        seen = {_key(d) for d in every}
        docs = every + [d for d in notable if _key(d) not in seen]
        docs.sort(key=lambda d: d["at"])  # stable: events of one instant keep their order
        return [d for d in docs if d["at"] >= since]

    async def drop_before(self, before: datetime) -> int:
        return await self.repo.drop_before(before)


def _key(doc: dict[str, Any]) -> str:
    """An event's identity (one an early version stored has no ``event_id``)."""
    return str(doc.get("event_id") or (doc["at"], doc["kind"], doc.get("data")))
