"""Each vehicle's failsafe policy, and each instance's watch state.

``failsafes``: one document per vehicle (``_id`` its id) holding the policy an admin or
its manager set, with ``version`` raised by each change; a write names the version it
read (compare and set), so two replicas changing one policy at once cannot both win.

``watch``: one document per instance (``_id`` its id): its home (the first position
it reported), the zones it is in breach of and whether its battery is low, each with
since when (``breach_since``: zone id -> time, ``battery_since``; absent in documents
written before they were kept), and the failsafe version it acknowledged; ``rev``
raised by each write, written by compare and set, so that of several replicas seeing
one change only one records it; ``rules_zones`` and ``rules_policy``, the versions of the
rules it was judged by (absent: 0).
"""

from __future__ import annotations

from server.domain.watch import RulesSeen, WatchState
from server.storage.backends import Doc, Duplicate, Store


def watch_state(doc: Doc | None) -> WatchState:
    """An instance's watch state as its document holds it (none: nothing wrong)."""
    if doc is None:
        return WatchState()
    return WatchState(
        frozenset(doc.get("breaches") or ()),
        bool(doc.get("low_battery")),
        dict(doc.get("breach_since") or {}),
        doc.get("battery_since"),
    )


def judged_by(doc: Doc | None) -> RulesSeen:
    """The rules the stored watch state was judged by."""
    if doc is None:
        return RulesSeen()
    return RulesSeen(int(doc.get("rules_zones") or 0), int(doc.get("rules_policy") or 0))


class SafetyRepo:
    def __init__(self, store: Store) -> None:
        self.failsafes = store["failsafes"]
        self.watch = store["watch"]

    async def policy(self, vehicle_id: str) -> Doc | None:
        doc = await self.failsafes.get(vehicle_id)
        if doc is not None:
            doc.pop("_id", None)
        return doc

    async def policies(self) -> dict[str, Doc]:
        return {d["vehicle_id"]: d for d in await self.failsafes.find({})}

    async def put_policy(self, doc: Doc, read_version: int) -> bool:
        """Write the policy if it is still the version read (0: there was none)."""
        doc = {**doc, "_id": doc["vehicle_id"]}
        if read_version == 0:
            try:
                await self.failsafes.insert(doc)
            except Duplicate:
                return False
            return True
        return await self.failsafes.replace(
            {"_id": doc["vehicle_id"], "version": read_version}, doc
        )

    async def watch_of(self, instance_id: str) -> Doc | None:
        return await self.watch.get(instance_id)

    async def watches_of(self, instance_ids: list[str]) -> list[Doc]:
        return await self.watch.get_many(instance_ids)

    async def begin_watch(
        self, instance_id: str, vehicle_id: str, home: tuple[float, float]
    ) -> None:
        """The instance's watch state, begun with its home (its first position); kept as
        it is when another replica began it first."""
        try:
            await self.watch.insert(
                {
                    "_id": instance_id,
                    "vehicle_id": vehicle_id,
                    "home": {"lat": home[0], "lon": home[1]},
                    "breaches": [],
                    "low_battery": False,
                    "rev": 0,
                }
            )
        except Duplicate:
            await self.watch.update(
                {"_id": instance_id, "home": None},
                set={"home": {"lat": home[0], "lon": home[1]}},
            )

    async def move_watch(
        self,
        instance_id: str,
        vehicle_id: str,
        read_rev: int | None,
        state: WatchState,
        rules: RulesSeen,
    ) -> bool:
        """Write the new state, judged by ``rules``, if it is still the one read
        (``read_rev``; None: none)."""
        fields = {
            "breaches": sorted(state.breaches),
            "low_battery": state.low_battery,
            "breach_since": dict(state.breach_since),
            "battery_since": state.battery_since,
            "rules_zones": rules.zones,
            "rules_policy": rules.policy,
        }
        if read_rev is None:
            try:
                await self.watch.insert(
                    {"_id": instance_id, "vehicle_id": vehicle_id, "home": None, "rev": 1, **fields}
                )
            except Duplicate:
                return False
            return True
        return await self.watch.update(
            {"_id": instance_id, "rev": read_rev}, set={**fields, "rev": read_rev + 1}
        )

    async def ack_failsafe(self, instance_id: str, vehicle_id: str, version: int) -> None:
        """The version of its policy the instance applies (the latest it said)."""
        if await self.watch.update({"_id": instance_id}, set={"failsafe_version": version}):
            return
        try:
            await self.watch.insert(
                {
                    "_id": instance_id,
                    "vehicle_id": vehicle_id,
                    "home": None,
                    "breaches": [],
                    "low_battery": False,
                    "rev": 0,
                    "failsafe_version": version,
                }
            )
        except Duplicate:
            await self.watch.update({"_id": instance_id}, set={"failsafe_version": version})
