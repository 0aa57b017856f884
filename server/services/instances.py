"""Instances and presence: start (or resume), heartbeat, finish, parameters.

Unfinished instances live in memory (hot state, one per vehicle) and are
written through to the store; ``last_seen`` and the latest position move on
every request, so they are written back by :meth:`InstanceService.sweep`
rather than on each call.
"""

from __future__ import annotations

import secrets
import time
from collections.abc import Awaitable, Callable
from datetime import datetime, timedelta
from typing import Any

from fleet_protocol import Sample, StartInstance
from server.domain.access import Principal
from server.domain.presence import Presence, presence_of
from server.errors import Forbidden, InstanceFinished, NotFound
from server.services.auth import AuthService
from server.services.events import EventService
from server.services.instance_state import InstanceState
from server.services.pacing import Pacer
from server.services.replicas import Announce, no_announce
from server.settings import Settings
from server.storage.instances import InstancesRepo

Clock = Callable[[], datetime]
FinishHook = Callable[[InstanceState, Principal | None], Awaitable[None]]
PresenceListener = Callable[[InstanceState, Presence], None]

__all__ = ["InstanceService", "InstanceState"]


class InstanceService:
    def __init__(
        self,
        settings: Settings,
        repo: InstancesRepo,
        auth: AuthService,
        events: EventService,
        clock: Clock,
    ) -> None:
        self.settings = settings
        self.repo = repo
        self.auth = auth
        self.events = events
        self.clock = clock
        self._by_id: dict[str, InstanceState] = {}
        self._by_vehicle: dict[str, InstanceState] = {}
        self.finish_hooks: list[FinishHook] = []
        self.presence_listeners: list[PresenceListener] = []
        #: Several replicas: the store is the truth (see server/services/replicas.py).
        self.shared = settings.shared_state
        self.announce: Announce = no_announce

    async def load(self) -> None:
        for doc in await self.repo.unfinished():
            state = InstanceState.from_doc(doc)
            state.presence = self._presence(state, self.clock())
            self._index(state)

    def _index(self, state: InstanceState) -> None:
        self._by_id[state.instance_id] = state
        self._by_vehicle[state.vehicle_id] = state

    # ---- lookups --------------------------------------------------------
    async def find(self, instance_id: str) -> InstanceState:
        state = self._by_id.get(instance_id)
        if state is None:
            doc = await self.repo.get(instance_id)
            if doc is None:
                raise NotFound(f"no instance {instance_id}")
            state = self._adopt(doc) if self.shared else InstanceState.from_doc(doc)
        return state

    async def fresh(self, instance_id: str) -> InstanceState:
        """:meth:`find`; on several replicas, merged with the store's copy first."""
        if not self.shared:
            return await self.find(instance_id)
        doc = await self.repo.get(instance_id)
        if doc is None:
            raise NotFound(f"no instance {instance_id}")
        return self._adopt(doc)

    async def for_vehicle_caller(self, principal: Principal, instance_id: str) -> InstanceState:
        """The instance a vehicle (or its gateway) calls about; it must be live."""
        state = await self.find(instance_id)
        if not principal.acts_for(state.vehicle_id):
            raise Forbidden(f"this token does not act for vehicle {state.vehicle_id}")
        if state.finished:
            raise InstanceFinished(f"instance {instance_id} is finished")
        return state

    async def for_viewer(self, principal: Principal, instance_id: str) -> InstanceState:
        state = await self.fresh(instance_id)
        if not principal.can_see(state.vehicle_id):
            raise Forbidden(f"no access to vehicle {state.vehicle_id}")
        return state

    def current_by_id(self, instance_id: str) -> InstanceState | None:
        """A live (unfinished) instance of this process, if any."""
        return self._by_id.get(instance_id)

    def current(self, vehicle_id: str) -> InstanceState | None:
        return self._by_vehicle.get(vehicle_id)

    async def current_or_latest(self, vehicle_id: str) -> InstanceState | None:
        state = self._by_vehicle.get(vehicle_id)
        if state is None:
            doc = await self.repo.latest_for_vehicle(vehicle_id)
            state = InstanceState.from_doc(doc) if doc else None
        return state

    def live(self) -> list[InstanceState]:
        return list(self._by_id.values())

    async def everyone(self) -> list[InstanceState]:
        """Every live instance: this replica's, or on several replicas the store's."""
        if not self.shared:
            return self.live()
        return [s for doc in await self.repo.unfinished() if not (s := self._adopt(doc)).finished]

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

    # ---- vehicle side ---------------------------------------------------
    async def start(self, principal: Principal, body: StartInstance) -> tuple[InstanceState, bool]:
        if not principal.acts_for(body.vehicle_id):
            raise Forbidden(f"this token does not act for vehicle {body.vehicle_id}")
        meta = await self.auth.vehicle_meta(body.vehicle_id)
        if meta is None:
            raise NotFound(f"no vehicle {body.vehicle_id}; an admin registers it first")
        now = self.clock()
        if self.shared:  # its unfinished instance may have been started on another replica
            await self._adopt_vehicle(body.vehicle_id)
        state = self._by_vehicle.get(body.vehicle_id)
        resumed = state is not None
        if state is None:
            state = InstanceState(
                instance_id="i-" + secrets.token_hex(8),
                vehicle_id=body.vehicle_id,
                name=body.name or meta.get("name") or body.vehicle_id,
                vehicle_type=body.vehicle_type,
                capabilities=list(body.capabilities),
                started_at=now,
                params=dict(body.params),
                params_updated_at=now if body.params else None,
                last_seen=now,
            )
            await self.repo.insert(state.to_doc())
            self._index(state)
        else:
            if body.name:
                state.name = body.name
            state.vehicle_type = body.vehicle_type
            state.capabilities = list(body.capabilities)
            self.merge_params(state, body.params)
            await self.repo.save(state.instance_id, state.to_doc())
        self.announce(state.instance_id, "instance")
        await self.events.record(
            "instance",
            vehicle_id=state.vehicle_id,
            instance_id=state.instance_id,
            actor=principal,
            data={"action": "resumed" if resumed else "started"},
        )
        self.touch(state)
        return state, resumed

    def touch(self, state: InstanceState) -> None:
        """Contact from the vehicle: any request, frame, or open long poll."""
        state.last_seen = self.clock()
        state.moved = True

    def merge_params(self, state: InstanceState, params: dict[str, Any]) -> None:
        """Shallow merge; ``null`` deletes a key."""
        if not params:
            return
        for key, value in params.items():
            if value is None:
                state.params.pop(key, None)
            else:
                state.params[key] = value
        state.params_updated_at = self.clock()
        state.dirty = True

    def set_position(
        self, state: InstanceState, sample: Sample, doc: dict[str, Any] | None = None
    ) -> bool:
        """Keep the sample with the greatest ``ts`` as the latest position.

        ``doc``: the sample already in its stored form (``model_dump(exclude_none=True)``).
        """
        current = state.position
        if current is not None and current["ts"] >= sample.ts:
            return False
        state.position = dict(doc) if doc is not None else sample.model_dump(exclude_none=True)
        state.moved = True
        return True

    def set_control_mode(self, state: InstanceState, mode: str | None) -> bool:
        if mode is None or mode == state.control_mode:
            return False
        state.control_mode = mode
        state.dirty = True
        return True

    async def finish(self, principal: Principal, state: InstanceState) -> None:
        state.finished_at = self.clock()
        self._set_presence(state, "finished")
        await self.repo.save(state.instance_id, state.to_doc())
        self._unindex(state)
        self.announce(state.instance_id, "instance")
        for hook in self.finish_hooks:
            await hook(state, principal)
        await self.events.record(
            "instance",
            vehicle_id=state.vehicle_id,
            instance_id=state.instance_id,
            actor=principal,
            data={"action": "finished"},
        )

    # ---- background -----------------------------------------------------
    def _set_presence(self, state: InstanceState, presence: Presence, *, tell: bool = True) -> None:
        state.presence = presence
        if tell:
            for listener in self.presence_listeners:
                listener(state, presence)

    async def sweep(self, *, everything: bool = False) -> None:
        """Presence changes by age, and write back what changed.

        Contact and position move with every frame of every vehicle: they are
        written at most every ``persist_interval_s`` (and on shutdown), the
        rest at once.
        """
        now = self.clock()
        tick = time.monotonic()
        every = self.settings.contact_write_s
        states = list(self._by_id.values())
        if self.shared:  # the vehicle may be in contact with another replica
            for state in states:
                if state.polling:  # an open long poll is contact; the others read it in the store
                    self.touch(state)
            changes = await self._recheck(states, now)
        else:
            # Most vehicles are online and fresh: one comparison each, presence_of for the rest.
            fresh = now - timedelta(seconds=self.settings.stale_after_s)
            changes = [
                (s, p)
                for s in states
                if not (s.presence == "online" and s.last_seen is not None and s.last_seen >= fresh)
                or s.finished
                if (p := self._presence(s, now)) != s.presence
            ]
        for state, presence in changes:
            told = not self.shared or await self.repo.claim_presence(state.instance_id, presence)
            self._set_presence(state, presence, tell=told)
            if told:  # several replicas: the one whose claim matched tells everyone
                await self.events.record(
                    "presence",
                    vehicle_id=state.vehicle_id,
                    instance_id=state.instance_id,
                    data={"presence": presence},
                )
                self.announce(state.instance_id, "instance")
        pacer = Pacer()
        for state in states:
            due = state.moved and (everything or tick - state.saved_at >= every)
            if state.dirty or due:
                await self._write(state, tick)
                await pacer.step()  # vehicles that connected together are due together

    async def save_now(self, state: InstanceState) -> None:
        """Several replicas: write a changed record at once (control mode decides submits)."""
        if self.shared and state.dirty:
            await self._write(state, state.saved_at)

    async def _write(self, state: InstanceState, tick: float) -> None:
        changed = state.dirty
        state.dirty = state.moved = False
        state.saved_at = tick
        # Only contact and position moved (most writes): those two fields alone.
        fields = state.to_doc() if changed else state.contact_doc()
        if not self.shared:
            await self.repo.save(state.instance_id, fields)
            return
        await self.repo.save_shared(state.instance_id, fields)
        if changed:
            self.announce(state.instance_id, "instance")

    # ---- several replicas -------------------------------------------------
    def _unindex(self, state: InstanceState) -> None:
        self._by_id.pop(state.instance_id, None)
        if self._by_vehicle.get(state.vehicle_id) is state:
            self._by_vehicle.pop(state.vehicle_id)

    def _adopt(self, doc: dict[str, Any]) -> InstanceState:
        """This replica's copy of a stored instance, caught up with ``doc``; an
        unfinished one is kept (another replica may have started it)."""
        state = self._by_id.get(doc["instance_id"])
        if state is None:
            state = InstanceState.from_doc(doc)
            if state.finished:
                return state  # read-only
            state.presence = self._presence(state, self.clock())
            former = self._by_vehicle.get(state.vehicle_id)
            if former is not None:
                self._unindex(former)  # finished elsewhere: the store has the newer one
            self._index(state)
            return state
        state.merge(doc)
        if state.finished:
            self._unindex(state)
        return state

    async def _adopt_vehicle(self, vehicle_id: str) -> None:
        """Catch up with the vehicle's unfinished instance in the store, wherever it began."""
        doc = await self.repo.unfinished_for_vehicle(vehicle_id)
        cached = self._by_vehicle.get(vehicle_id)
        if cached is not None and (doc is None or doc["instance_id"] != cached.instance_id):
            self._unindex(cached)  # finished on another replica
        if doc is not None:
            self._adopt(doc)

    async def refresh(self, instance_id: str) -> bool:
        """Another replica changed the instance: catch up. Whether it is finished."""
        doc = await self.repo.get(instance_id)
        if doc is None:
            if (gone := self._by_id.get(instance_id)) is not None:
                self._unindex(gone)
            return True
        if instance_id in self._by_id:
            self._adopt(doc)
        return doc.get("finished_at") is not None

    async def _recheck(
        self, states: list[InstanceState], now: datetime
    ) -> list[tuple[InstanceState, Presence]]:
        """Several replicas: the presence changes due, once the contact other replicas
        wrote is read back (one read for all). A copy is read back a little before it
        would change (``contact_write_s`` ahead), so that it never looks stale here
        while the vehicle is in contact with another replica."""
        ahead = now + timedelta(seconds=self.settings.contact_write_s)
        near = [s for s in states if self._presence(s, ahead) != s.presence]
        if not near:
            return []
        stored = await self.repo.contacts([s.instance_id for s in near])
        by_id = {d["instance_id"]: d for d in stored}
        out = []
        for state in near:
            if (doc := by_id.get(state.instance_id)) is not None:
                state.merge_contact(doc)
            if (presence := self._presence(state, now)) != state.presence:
                out.append((state, presence))
        return out

    async def drop_finished_before(self, before: datetime) -> int:
        return await self.repo.drop_finished_before(before)
