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
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from fleet_protocol import Sample, StartInstance
from server.domain.access import Principal
from server.domain.presence import Presence, presence_of
from server.errors import Forbidden, InstanceFinished, NotFound
from server.services.auth import AuthService
from server.services.events import EventService
from server.settings import Settings
from server.storage.instances import InstancesRepo

Clock = Callable[[], datetime]
FinishHook = Callable[["InstanceState", Principal | None], Awaitable[None]]
PresenceListener = Callable[["InstanceState", Presence], None]


@dataclass
class InstanceState:
    instance_id: str
    vehicle_id: str
    name: str
    vehicle_type: str
    capabilities: list[str]
    started_at: datetime
    params: dict[str, Any] = field(default_factory=dict)
    params_updated_at: datetime | None = None
    last_seen: datetime | None = None
    control_mode: str = "idle"
    position: dict[str, Any] | None = None
    finished_at: datetime | None = None
    presence: Presence = "offline"
    polling: int = 0  # open long polls: contact while open
    dirty: bool = False  # params or control mode changed: written at the next sweep
    moved: bool = False  # last_seen or position moved: written every persist_interval_s
    saved_at: float = 0.0  # monotonic time of the last write

    @property
    def finished(self) -> bool:
        return self.finished_at is not None

    def position_json(self) -> dict[str, Any] | None:
        if self.position is None:
            return None
        return Sample.model_validate(self.position).model_dump(mode="json", exclude_none=True)

    def to_doc(self) -> dict[str, Any]:
        return {
            "instance_id": self.instance_id,
            "vehicle_id": self.vehicle_id,
            "name": self.name,
            "vehicle_type": self.vehicle_type,
            "capabilities": self.capabilities,
            "started_at": self.started_at,
            "params": self.params,
            "params_updated_at": self.params_updated_at,
            "last_seen": self.last_seen,
            "control_mode": self.control_mode,
            "position": self.position,
            "finished_at": self.finished_at,
        }

    @classmethod
    def from_doc(cls, doc: dict[str, Any]) -> InstanceState:
        fields: dict[str, Any] = {
            k: doc.get(k)
            for k in (
                "instance_id",
                "vehicle_id",
                "name",
                "vehicle_type",
                "capabilities",
                "started_at",
                "params",
                "params_updated_at",
                "last_seen",
                "control_mode",
                "position",
                "finished_at",
            )
        }
        fields["params"] = fields["params"] or {}
        fields["capabilities"] = fields["capabilities"] or []
        fields["control_mode"] = fields["control_mode"] or "idle"
        return cls(**fields)


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
            state = InstanceState.from_doc(doc)  # a finished one: read-only
        return state

    async def for_vehicle_caller(self, principal: Principal, instance_id: str) -> InstanceState:
        """The instance a vehicle (or its gateway) calls about; it must be live."""
        state = await self.find(instance_id)
        if not principal.acts_for(state.vehicle_id):
            raise Forbidden(f"this token does not act for vehicle {state.vehicle_id}")
        if state.finished:
            raise InstanceFinished(f"instance {instance_id} is finished")
        return state

    async def for_viewer(self, principal: Principal, instance_id: str) -> InstanceState:
        state = await self.find(instance_id)
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

    def set_position(self, state: InstanceState, sample: Sample) -> bool:
        """Keep the sample with the greatest ``ts`` as the latest position."""
        current = state.position
        if current is not None and current["ts"] >= sample.ts:
            return False
        state.position = sample.model_dump(exclude_none=True)
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
        self._by_id.pop(state.instance_id, None)
        if self._by_vehicle.get(state.vehicle_id) is state:
            self._by_vehicle.pop(state.vehicle_id)
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
    def _set_presence(self, state: InstanceState, presence: Presence) -> None:
        state.presence = presence
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
        every = self.settings.persist_interval_s
        for state in list(self._by_id.values()):
            presence = self._presence(state, now)
            if presence != state.presence:
                self._set_presence(state, presence)
                await self.events.record(
                    "presence",
                    vehicle_id=state.vehicle_id,
                    instance_id=state.instance_id,
                    data={"presence": presence},
                )
            due = state.moved and (everything or tick - state.saved_at >= every)
            if state.dirty or due:
                state.dirty = state.moved = False
                state.saved_at = tick
                await self.repo.save(state.instance_id, state.to_doc())

    async def drop_finished_before(self, before: datetime) -> int:
        return await self.repo.drop_finished_before(before)
