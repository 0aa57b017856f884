"""Operating areas and no-go zones: drawn by an admin, checked by every submit, watched
in every vehicle's telemetry.

The set has a version, raised by each change (an event says so): a command records the
version it was checked against, and one checked against an older version is checked
again before it is handed out (:mod:`server.services.commands`). This replica keeps the
set it last read and reads it again when the stored version moves. A change made here
is told as :class:`~server.domain.events.ZonesChanged` (the watch judges the vehicles
again; the other replicas hear of it on the bus).
"""

from __future__ import annotations

import secrets
from datetime import datetime
from typing import Any

from fleet_protocol import CreateZone, PatchZone
from server.domain.clock import Clock
from server.domain.events import ZonesChanged
from server.domain.zones import Area, ZoneSet, zone_changes
from server.errors import Invalid, NotFound
from server.services.auth import AuthService
from server.services.events import EventService
from server.services.messagebus import MessageBus
from server.services.obstacles import check_polygon
from server.settings import Settings
from server.storage.backends import Doc
from server.storage.zones import ZonesRepo


def area_of(doc: Doc) -> Area:
    rings = tuple(
        tuple((float(lat), float(lon)) for lon, lat in ring)
        for ring in doc["polygon"]["coordinates"]
    )
    return Area(
        doc["zone_id"],
        doc["name"],
        doc["kind"],
        rings,
        frozenset(doc.get("vehicles") or ()),
        float(doc.get("clearance_m") or 0.0),
    )


class ZoneService:
    def __init__(
        self,
        settings: Settings,
        repo: ZonesRepo,
        auth: AuthService,
        events: EventService,
        messages: MessageBus,
        clock: Clock,
    ) -> None:
        self.settings = settings
        self.repo = repo
        self.auth = auth
        self.events = events
        self.messages = messages
        self.clock = clock
        self._set = ZoneSet()

    async def load(self) -> None:
        await self.repo.ensure_indexes()

    async def current(self) -> ZoneSet:
        """The set as the store has it now (read again only when its version moved)."""
        version = await self.repo.version()
        if version != self._set.version:
            docs = await self.repo.all()
            self._set = ZoneSet(tuple(area_of(d) for d in docs), version)
        return self._set

    def known(self) -> ZoneSet:
        """The set as this replica last read it (no store read): the hot path's."""
        return self._set

    async def all(self) -> tuple[list[Doc], int]:
        return await self.repo.all(), await self.repo.version()

    async def at(self, when: datetime) -> tuple[list[Doc], int]:
        """The set as it was at ``when``, in its order, and its version then: each zone
        as its latest kept version up to then made it (none if deleted); a zone with
        no version kept (drawn before versions were, unchanged since) as it is, from
        when it was drawn."""
        latest: dict[str, Doc] = {}
        version = 0
        for kept in await self.repo.versions_until(when):
            latest[kept["zone_id"]] = kept
            version = max(version, int(kept["version"]))
        zones = [v["zone"] for v in latest.values() if not v["deleted"]]
        now = await self.repo.all()
        unkept = [d for d in now if d["zone_id"] not in latest]
        with_versions = await self.repo.zones_with_versions(d["zone_id"] for d in unkept)
        for doc in unkept:
            if doc["zone_id"] not in with_versions and doc["created_at"] <= when:
                zones.append(doc)
                version = max(version, int(doc["created_version"]))
        zones.sort(key=lambda d: (int(d["created_version"]), d["zone_id"]))
        return zones, version

    async def changes(self, start: datetime, end: datetime) -> list[Doc]:
        """Each change kept after ``start`` and up to ``end`` (the zone as it left it)."""
        return await self.repo.versions_between(start, end)

    async def get(self, zone_id: str) -> Doc:
        doc = await self.repo.get(zone_id)
        if doc is None:
            raise NotFound(f"no zone {zone_id}")
        return doc

    async def create(self, body: CreateZone, actor: Any) -> Doc:
        check_polygon(body.polygon)
        await self._check(body.kind, body.vehicles)
        now = self.clock()
        version = await self.repo.next_version()
        doc: dict[str, Any] = {
            "zone_id": "z-" + secrets.token_hex(8),
            "name": body.name,
            "kind": body.kind,
            "polygon": body.polygon.model_dump(mode="json"),
            "vehicles": sorted(set(body.vehicles)),
            "clearance_m": self.settings.safety_radius_m
            if body.clearance_m is None
            else body.clearance_m,
            "version": version,
            "created_version": version,  # the list's order
            "created_at": now,
            "updated_at": now,
        }
        await self.repo.insert(doc)
        await self.repo.add_version(doc, _to_ms(now))
        await self._changed(doc, "created", actor)
        return doc

    async def patch(self, zone_id: str, body: PatchZone, actor: Any) -> Doc:
        doc = await self.get(zone_id)
        if body.polygon is not None:
            check_polygon(body.polygon)
        changes = zone_changes(
            doc,
            {
                "kind": body.kind,
                "name": body.name,
                "polygon": None if body.polygon is None else body.polygon.model_dump(mode="json"),
                "vehicles": None if body.vehicles is None else sorted(set(body.vehicles)),
                "clearance_m": body.clearance_m,
            },
        )
        if not changes:
            return doc  # nothing changes: the same version, the same updated_at
        await self._kept_before(doc)
        doc.update(changes)
        await self._check(doc["kind"], doc["vehicles"])
        doc["version"] = await self.repo.next_version()
        doc["updated_at"] = self.clock()
        if not await self.repo.replace(doc):
            raise NotFound(f"no zone {zone_id}")
        await self.repo.add_version(doc, _to_ms(doc["updated_at"]))
        await self._changed(doc, "changed", actor)
        return doc

    async def delete(self, zone_id: str, actor: Any) -> Doc:
        doc = await self.get(zone_id)
        await self._kept_before(doc)
        if not await self.repo.delete(zone_id):
            raise NotFound(f"no zone {zone_id}")
        doc["version"] = await self.repo.next_version()
        await self.repo.add_version(doc, _to_ms(self.clock()), deleted=True)
        await self._changed(doc, "deleted", actor)
        return doc

    async def _kept_before(self, doc: Doc) -> None:
        """A zone drawn before versions were kept: its shape until this change, kept
        from when it last changed (its past before that is not known)."""
        if not await self.repo.has_versions(doc["zone_id"]):
            await self.repo.add_version(
                dict(doc), _to_ms(doc.get("updated_at") or doc["created_at"])
            )

    async def _check(self, kind: str, vehicles: list[str]) -> None:
        if kind == "operating_area" and not vehicles:
            raise Invalid(
                "an operating area holds the vehicles it lists: list at least one",
                details=[{"field": "vehicles", "message": "at least one vehicle"}],
            )
        missing = [v for v in vehicles if await self.auth.vehicle_meta(v) is None]
        if missing:
            raise Invalid(
                "unknown vehicles",
                details=[{"field": "vehicles", "message": f"no vehicle {v}"} for v in missing],
            )

    async def _changed(self, doc: Doc, action: str, actor: Any) -> None:
        data = {
            "zone_id": doc["zone_id"],
            "name": doc["name"],
            "kind": doc["kind"],
            "action": action,
            "version": doc["version"],
        }
        await self.current()  # this replica sees its own change at once
        await self.events.record("zones_changed", actor=actor, data=data)
        for vehicle_id in doc.get("vehicles") or ():
            await self.events.record("zones_changed", vehicle_id=vehicle_id, actor=actor, data=data)
        await self.messages.emit(ZonesChanged(int(doc["version"])))


def _to_ms(when: datetime) -> datetime:
    """``when`` to the millisecond, as the wire says times (and MongoDB keeps them): a
    version asked for at a time the server said is found at that time."""
    return when.replace(microsecond=when.microsecond // 1000 * 1000)
