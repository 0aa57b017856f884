"""This replica's copies of the instances, and the lookups on them.

The store holds every instance; this replica keeps a copy
(:class:`~server.services.instance_state.InstanceState`) of the unfinished ones
it deals with, by id and by vehicle, caught up with the store when it reads it
(:meth:`InstanceCopies._adopt`: an unfinished one is kept, a finished one read
only). A lookup answers from the copy or the store's: for a vehicle (or its
gateway) calling about its live instance, or for a viewer of the vehicle; an
instance of another vehicle, or of one the caller may not see, is not found, as
an unknown one is (docs/security.md).
:class:`~server.services.instances.InstanceService` builds the life of an
instance (start, contact, finish, the presence sweep) on these.
"""

from __future__ import annotations

import time
from datetime import datetime
from typing import Any

from server.domain.access import Principal
from server.domain.clock import Clock
from server.domain.presence import Presence, is_online, online_since, presence_of
from server.errors import InstanceFinished as Finished
from server.errors import NotFound
from server.services.instance_state import InstanceState
from server.services.pacing import period_of
from server.settings import Settings
from server.storage.instances import InstancesRepo

__all__ = ["InstanceCopies"]


class InstanceCopies:
    """This replica's copies and the lookups (see the module); the base of
    :class:`~server.services.instances.InstanceService`."""

    def __init__(self, settings: Settings, repo: InstancesRepo, clock: Clock) -> None:
        self.settings = settings
        self.repo = repo
        self.clock = clock
        self._by_id: dict[str, InstanceState] = {}
        self._by_vehicle: dict[str, InstanceState] = {}
        #: The store's courses (``online_positions``), when they were read, and the
        #: instances this replica saw finish since (their stored copy may say otherwise).
        self._courses: dict[str, dict[str, Any]] | None = None
        self._courses_read = 0.0
        self._ended: set[str] = set()

    async def load(self) -> None:
        await self.repo.ensure_indexes()
        read_at = time.monotonic()
        for doc in await self.repo.unfinished():
            self._adopt(doc, read_at)

    # ---- lookups --------------------------------------------------------
    async def find(self, instance_id: str) -> InstanceState:
        """The instance: this replica's copy, or the store's."""
        state = self._by_id.get(instance_id)
        if state is None:
            read_at = time.monotonic()
            doc = await self.repo.get(instance_id)
            if doc is None:
                raise NotFound(f"no instance {instance_id}")
            state = self._adopt(doc, read_at)
        return state

    async def fresh(self, instance_id: str) -> InstanceState:
        """The instance as the store has it now (this replica's copy caught up)."""
        read_at = time.monotonic()
        doc = await self.repo.get(instance_id)
        if doc is None:
            raise NotFound(f"no instance {instance_id}")
        return self._adopt(doc, read_at)

    async def for_vehicle_caller(self, principal: Principal, instance_id: str) -> InstanceState:
        """The instance a vehicle (or its gateway) calls about; it must be live. Another
        vehicle's is not found, as an unknown one is (docs/security.md)."""
        return self._callers(principal, await self.find(instance_id))

    def kept_for_vehicle_caller(
        self, principal: Principal, instance_id: str
    ) -> InstanceState | None:
        """:meth:`for_vehicle_caller` from this replica's copies alone: None when it keeps
        no copy of the instance (then the store has to be asked)."""
        state = self._by_id.get(instance_id)
        return None if state is None else self._callers(principal, state)

    @staticmethod
    def _callers(principal: Principal, state: InstanceState) -> InstanceState:
        if not principal.acts_for(state.vehicle_id):
            raise NotFound(f"no instance {state.instance_id}")
        if state.finished:
            raise Finished(f"instance {state.instance_id} is finished")
        return state

    async def for_viewer(self, principal: Principal, instance_id: str) -> InstanceState:
        """The instance, if the caller may see its vehicle: if not, it is not found, as an
        unknown one is (docs/security.md)."""
        state = await self.fresh(instance_id)
        if not principal.can_see(state.vehicle_id):
            raise NotFound(f"no instance {instance_id}")
        return state

    def current_by_id(self, instance_id: str) -> InstanceState | None:
        """This replica's copy of an unfinished instance, if it keeps one."""
        return self._by_id.get(instance_id)

    def current(self, vehicle_id: str) -> InstanceState | None:
        return self._by_vehicle.get(vehicle_id)

    async def current_or_latest(self, vehicle_id: str) -> InstanceState | None:
        """The vehicle's unfinished instance, else its latest one, else None."""
        state = self._by_vehicle.get(vehicle_id)
        if state is not None:
            return state
        read_at = time.monotonic()
        doc = await self.repo.latest_for_vehicle(vehicle_id)
        return self._adopt(doc, read_at) if doc is not None else None

    def live(self) -> list[InstanceState]:
        """The unfinished instances this replica keeps a copy of."""
        return list(self._by_id.values())

    async def everyone(self) -> list[InstanceState]:
        """Every unfinished instance in the store."""
        read_at = time.monotonic()
        docs = await self.repo.unfinished()
        return [s for doc in docs if not (s := self._adopt(doc, read_at)).finished]

    async def online_positions(self) -> list[tuple[str, str, dict[str, Any]]]:
        """``(vehicle_id, instance_id, latest sample)`` of every online instance with a
        position, on every replica: this replica's own copies, and the store's few fields
        for the others (not whole instances). The store's are read again once every
        ``contact_write_s`` (the replicas write contact no more often than that), so a
        pass costs a walk through this replica's copies and no store read in between."""
        now = self.clock()
        tick = time.monotonic()
        if self._courses is None or tick - self._courses_read >= self.settings.contact_write_s:
            # This replica's own are read from its copies below, at every pass.
            courses = await self.repo.courses(skip=self._by_id)
            self._courses = {d["instance_id"]: d for d in courses}
            self._courses_read = tick
            self._ended.clear()
        since = online_since(now, self.settings.stale_after_s)
        out = [
            (state.vehicle_id, state.instance_id, state.position)
            for state in self._by_id.values()
            if state.position is not None
            and is_online(
                state.last_seen, since, finished=state.finished, polling=state.polling > 0
            )
        ]
        by_id = self._by_id
        for instance_id, doc in self._courses.items():
            if instance_id in by_id or instance_id in self._ended:
                continue
            position = doc.get("position")
            presence = presence_of(
                doc.get("last_seen"),
                now,
                stale_after_s=self.settings.stale_after_s,
                offline_after_s=self.settings.offline_after_s,
            )
            if presence == "online" and position is not None:
                out.append((doc["vehicle_id"], instance_id, position))
        return out

    def presence(self, state: InstanceState) -> Presence:
        return self._presence(state, self.clock())

    def _presence(self, state: InstanceState, now: datetime) -> Presence:
        return presence_of(
            state.last_seen,
            now,
            stale_after_s=self.settings.stale_after_s,
            offline_after_s=self.settings.offline_after_s,
            finished=state.finished,
            polling=state.polling > 0,
        )

    # ---- this replica's copies -------------------------------------------
    def _index(self, state: InstanceState) -> None:
        if not state.contact_every_s:  # vehicles that connected together drift apart
            state.contact_every_s = period_of(state.instance_id, self.settings.contact_write_s)
        self._by_id[state.instance_id] = state
        self._by_vehicle[state.vehicle_id] = state

    def _unindex(self, state: InstanceState) -> None:
        self._by_id.pop(state.instance_id, None)
        if self._courses is not None and state.instance_id in self._courses:
            self._ended.add(state.instance_id)
        if self._by_vehicle.get(state.vehicle_id) is state:
            self._by_vehicle.pop(state.vehicle_id)

    def _adopt(self, doc: dict[str, Any], read_at: float | None = None) -> InstanceState:
        """This replica's copy of a stored instance, caught up with ``doc`` (read from the
        store from ``read_at``, monotonic, when known). An unfinished one is kept (it may
        be the vehicle's newest: an older copy of the vehicle goes)."""
        state = self._by_id.get(doc["instance_id"])
        if state is None:
            state = InstanceState.from_doc(doc)
            # The presence last told (a change since is told by the next sweep).
            state.presence = doc.get("presence") or self._presence(state, self.clock())
            if state.finished:
                state.presence = "finished"
                return state  # read-only
            former = self._by_vehicle.get(state.vehicle_id)
            if former is not None:
                self._unindex(former)  # finished elsewhere: the store has the newer one
            self._index(state)
            return state
        state.merge(doc, read_at)
        if state.finished:
            self._unindex(state)
        return state

    async def refresh(self, instance_id: str) -> bool:
        """Another replica changed the instance: catch up. Whether it is finished (or gone)."""
        read_at = time.monotonic()
        doc = await self.repo.get(instance_id)
        if doc is None:
            if (gone := self._by_id.get(instance_id)) is not None:
                self._unindex(gone)
            return True
        if instance_id in self._by_id:
            self._adopt(doc, read_at)
        return doc.get("finished_at") is not None
