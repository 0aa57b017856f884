"""Instances (a vehicle's session with the server), and which one is each vehicle's.

An instance's ``_id`` is its instance id. ``vehicle_instances`` holds one
document per vehicle with an unfinished instance (``_id``: the vehicle id):
the store's own key makes it one per vehicle, however many replicas start
one at the same moment. ``presence`` holds each instance's presence changes,
``_id = "<instance_id>/<seq, 6 digits>"``: the key makes each ``seq`` one
change at most, so of several replicas telling the same change the first
insert tells it. A conditional update would not do: FerretDB 1.24 reads the
document, applies the update and writes the whole document back, with
nothing between, so two replicas' ``presence != new`` updates both match,
and a contact write racing one puts the former presence back.

What the vehicle sends free-form (its ``params``, and its latest sample in
``position``, whose ``data`` is free-form) is stored packed as one BSON
binary each: the store holds it whatever its shape (FerretDB, for one,
refuses arrays nested in arrays, which MongoDB takes) and never reads into it.
"""

from __future__ import annotations

from collections.abc import Container
from datetime import datetime
from typing import Any

import bson

from server.storage.backends import ENCODE_ERRORS, Doc, Duplicate, Rejected, Store

#: Fields stored packed (free-form: the store never looks inside).
PACKED = ("params", "position")
_CODEC: bson.CodecOptions[Any] = bson.CodecOptions(tz_aware=True)


def _pack(fields: dict[str, Any]) -> dict[str, Any]:
    out = dict(fields)
    for name in PACKED:
        value = out.get(name)
        if value is not None:
            try:
                out[name] = bson.Binary(bson.encode({"v": value}))
            except ENCODE_ERRORS as exc:
                raise Rejected(f"{name}: {type(exc).__name__}: {exc}") from exc
    return out


def _unpack(doc: Doc | None) -> Doc | None:
    if doc is None:
        return None
    for name in PACKED:
        value = doc.get(name)
        if isinstance(value, bytes):
            doc[name] = bson.decode(value, _CODEC)["v"]
    return doc


class InstancesRepo:
    def __init__(self, store: Store) -> None:
        self.instances = store["instances"]
        self.current = store["vehicle_instances"]
        self.presence = store["presence"]

    async def ensure_indexes(self) -> None:
        await self.instances.create_index([("vehicle_id", 1), ("started_at", 1)])
        await self.instances.create_index([("finished_at", 1)])
        await self.presence.create_index([("instance_id", 1), ("seq", 1)])

    async def get(self, instance_id: str) -> Doc | None:
        return _unpack(await self.instances.get(instance_id))

    async def get_many(self, instance_ids: list[str]) -> list[Doc]:
        return [_unpack(d) or d for d in await self.instances.get_many(instance_ids)]

    async def courses(self, skip: Container[str] = ()) -> list[Doc]:
        """Each unfinished instance's ids, last contact and latest sample, and no more (the
        collision forecast reads them), but those in ``skip`` (whose latest sample the
        caller has). Their ids are read first: when all are in ``skip`` (one replica),
        nothing more is."""
        unfinished = {"finished_at": None}
        ids = await self.instances.find(unfinished, projection={"_id": 1})
        if all(d["_id"] in skip for d in ids):
            return []
        fields = {"instance_id": 1, "vehicle_id": 1, "last_seen": 1, "position": 1}
        docs = await self.instances.find(unfinished, projection=fields)
        return [_unpack(d) or d for d in docs if d["_id"] not in skip]

    async def unfinished(self) -> list[Doc]:
        return [_unpack(d) or d for d in await self.instances.find({"finished_at": None})]

    async def latest_for_vehicle(self, vehicle_id: str) -> Doc | None:
        doc = await self.instances.find_one({"vehicle_id": vehicle_id}, sort=[("started_at", -1)])
        return _unpack(doc)

    async def current_id(self, vehicle_id: str) -> str | None:
        """The vehicle's unfinished instance, as its claim says."""
        doc = await self.current.get(vehicle_id)
        return None if doc is None else str(doc["instance_id"])

    async def claim(self, vehicle_id: str, instance_id: str) -> bool:
        """Make ``instance_id`` the vehicle's one unfinished instance; False when another is."""
        try:
            await self.current.insert({"_id": vehicle_id, "instance_id": instance_id})
        except Duplicate:
            return False
        return True

    async def release(self, vehicle_id: str, instance_id: str) -> None:
        """The vehicle's claim, if it is still this instance's, ends."""
        await self.current.delete({"_id": vehicle_id, "instance_id": instance_id})

    async def insert(self, doc: Doc) -> None:
        await self.instances.insert(_pack({**doc, "_id": doc["instance_id"]}))

    async def save(self, instance_id: str, fields: dict[str, Any]) -> None:
        """Write fields of the record; ``last_seen`` never moves back."""
        seen = fields.get("last_seen")
        rest = _pack({k: v for k, v in fields.items() if k != "last_seen"})
        await self.instances.update(
            {"_id": instance_id}, set=rest, max={"last_seen": seen} if seen is not None else None
        )

    async def claim_presence(self, instance_id: str, seq: int, presence: str, at: datetime) -> bool:
        """Tell ``presence`` as the instance's ``seq``-th presence change: whether this
        caller took ``seq`` (False: another replica told one under it first)."""
        try:
            await self.presence.insert(
                {
                    "_id": f"{instance_id}/{seq:06d}",
                    "instance_id": instance_id,
                    "seq": seq,
                    "presence": presence,
                    "at": at,
                }
            )
        except Duplicate:
            return False
        return True

    async def last_presence(self, instance_id: str) -> Doc | None:
        """The instance's latest presence change told (``seq``, ``presence``), if any."""
        return await self.presence.find_one({"instance_id": instance_id}, sort=[("seq", -1)])

    async def note_presence(self, instance_id: str, seq: int, presence: str) -> None:
        """Keep the latest presence change told on the record too (``presence_seq``), for
        those who read the record; an earlier one never replaces a later."""
        older = {"$or": [{"presence_seq": {"$lt": seq}}, {"presence_seq": {"$exists": False}}]}
        await self.instances.update(
            {"_id": instance_id, **older}, set={"presence": presence, "presence_seq": seq}
        )

    async def drop_finished_before(self, before: datetime) -> int:
        """Drop the instances finished before ``before``; their presence changes first, so
        that a failure in between leaves none whose instance is gone."""
        flt = {"finished_at": {"$lt": before}}
        gone = [d["_id"] for d in await self.instances.find(flt, projection={"_id": 1})]
        if not gone:
            return 0
        await self.presence.delete({"instance_id": {"$in": gone}})
        return await self.instances.delete({"_id": {"$in": gone}})
