"""Instances and presence: start (or resume), heartbeat, finish, parameters.

The store holds every instance; this replica keeps a copy of the unfinished
ones it deals with (:class:`InstanceState`). Contact and the latest position
move with every frame of every vehicle, so they live in the copy and are
written back by :meth:`InstanceService.sweep` every ``contact_write_s``;
parameters are written back at the next sweep; a change of control mode and
a finish are written at once (decisions depend on them). Before a presence
change is declared, the contact other replicas wrote is read back, and of
several replicas seeing it only one tells it: a change is told under the
instance's next number (``presence_seq``), and the store keeps one change per
number (its key), so the first to insert it tells it. One replica or several,
the algorithm is this one.
"""

from __future__ import annotations

import secrets
import time
from datetime import datetime, timedelta
from typing import Any

from fleet_protocol import Sample, StartInstance
from server.domain.access import Principal
from server.domain.clock import Clock
from server.domain.events import InstanceFinished, PresenceChanged, StateWritten
from server.domain.params import params_after
from server.domain.presence import Presence, is_online, online_since, presence_of
from server.errors import Conflict, Forbidden, NotFound, Unavailable
from server.errors import InstanceFinished as Finished
from server.services.auth import AuthService
from server.services.dead_letters import DeadLetters
from server.services.events import EventService
from server.services.instance_state import InstanceState
from server.services.messagebus import MessageBus
from server.services.pacing import Pacer, period_of
from server.settings import Settings
from server.storage.instances import InstancesRepo

__all__ = ["InstanceService", "InstanceState"]

#: Tries to claim a vehicle's instance while other replicas claim and finish it.
_CLAIM_TRIES = 5


class InstanceService:
    def __init__(
        self,
        settings: Settings,
        repo: InstancesRepo,
        auth: AuthService,
        events: EventService,
        messages: MessageBus,
        dead_letters: DeadLetters,
        clock: Clock,
    ) -> None:
        self.settings = settings
        self.repo = repo
        self.auth = auth
        self.events = events
        self.messages = messages
        self.dead_letters = dead_letters
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
        for doc in await self.repo.unfinished():
            self._adopt(doc)

    # ---- lookups --------------------------------------------------------
    async def find(self, instance_id: str) -> InstanceState:
        """The instance: this replica's copy, or the store's."""
        state = self._by_id.get(instance_id)
        if state is None:
            doc = await self.repo.get(instance_id)
            if doc is None:
                raise NotFound(f"no instance {instance_id}")
            state = self._adopt(doc)
        return state

    async def fresh(self, instance_id: str) -> InstanceState:
        """The instance as the store has it now (this replica's copy caught up)."""
        doc = await self.repo.get(instance_id)
        if doc is None:
            raise NotFound(f"no instance {instance_id}")
        return self._adopt(doc)

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
        doc = await self.repo.latest_for_vehicle(vehicle_id)
        return self._adopt(doc) if doc is not None else None

    def live(self) -> list[InstanceState]:
        """The unfinished instances this replica keeps a copy of."""
        return list(self._by_id.values())

    async def everyone(self) -> list[InstanceState]:
        """Every unfinished instance in the store."""
        return [s for doc in await self.repo.unfinished() if not (s := self._adopt(doc)).finished]

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

    # ---- vehicle side ---------------------------------------------------
    async def start(self, principal: Principal, body: StartInstance) -> tuple[InstanceState, bool]:
        if not principal.acts_for(body.vehicle_id):
            raise Forbidden(f"this token does not act for vehicle {body.vehicle_id}")
        meta = await self.auth.vehicle_meta(body.vehicle_id)
        if meta is None:
            raise NotFound(f"no vehicle {body.vehicle_id}; an admin registers it first")
        state, created = await self._claimed(body, meta)
        resumed = not created
        if resumed:
            if body.name:
                state.name = body.name
            if body.vehicle_type:
                state.vehicle_type = body.vehicle_type
            state.capabilities = list(body.capabilities)
            self.merge_params(state, body.params, starting=True)
            await self._write(state, time.monotonic(), whole=True)
        await self.events.record(
            "instance",
            vehicle_id=state.vehicle_id,
            instance_id=state.instance_id,
            actor=principal,
            data={"action": "resumed" if resumed else "started"},
        )
        self.touch(state)
        return state, resumed

    async def _claimed(
        self, body: StartInstance, meta: dict[str, Any]
    ) -> tuple[InstanceState, bool]:
        """The vehicle's unfinished instance as the store says, or a new one (True)."""
        vehicle_id = body.vehicle_id
        for _ in range(_CLAIM_TRIES):
            current = await self.repo.current_id(vehicle_id)
            if current is not None:
                doc = await self.repo.get(current)
                if doc is not None and doc.get("finished_at") is None:
                    return self._adopt(doc), False
                await self.repo.release(vehicle_id, current)  # a claim left by a crash
                continue
            now = self.clock()
            state = InstanceState(
                instance_id="i-" + secrets.token_hex(8),
                vehicle_id=vehicle_id,
                name=body.name or meta.get("name") or vehicle_id,
                vehicle_type=body.vehicle_type or meta.get("vehicle_type") or "usv",
                capabilities=list(body.capabilities),
                started_at=now,
                params=dict(body.params),
                params_updated_at=now if body.params else None,
                last_seen=now,
                presence="online",
            )
            if not await self.repo.claim(vehicle_id, state.instance_id):
                continue  # another replica started one at the same moment: take it up
            await self.repo.insert({**state.to_doc(), "presence": "online", "presence_seq": 0})
            self._index(state)
            self.messages.emit_now(StateWritten(state.instance_id, "instance"))
            return state, True
        raise Conflict(f"vehicle {vehicle_id}'s instance keeps changing; try again")

    def touch(self, state: InstanceState, now: datetime | None = None) -> None:
        """Contact from the vehicle: any request, frame, or open long poll (at ``now``,
        read from the clock when not given)."""
        state.last_seen = self.clock() if now is None else now
        state.moved = True

    def merge_params(
        self,
        state: InstanceState,
        params: dict[str, Any],
        now: datetime | None = None,
        *,
        starting: bool = False,
    ) -> None:
        """Shallow merge; ``null`` deletes a key. ``now``: the call's time (else the clock's).

        The merged parameters keep to one call's bounds (``params_after``): past them,
        422 naming ``params`` and nothing changed; a vehicle resuming its instance
        (``starting``) whose parameters would pass them starts from those it sends."""
        if not params:
            return
        merged = params_after(state.params, params, starting=starting)
        if merged is not None:
            state.params = merged
        state.params_updated_at = self.clock() if now is None else now
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

    async def set_control_mode(
        self, state: InstanceState, mode: str | None, since: datetime | None = None
    ) -> bool:
        """The vehicle's control mode, entered ``since`` (None: not known); written at once
        (submits depend on it)."""
        if mode is None or mode == state.control_mode:
            return False
        state.control_mode, state.control_mode_since = mode, since
        state.dirty = True
        await self._write(state, time.monotonic(), whole=True)
        return True

    async def finish(self, principal: Principal, state: InstanceState) -> None:
        state.finished_at = self.clock()
        state.presence = "finished"
        await self.repo.save(state.instance_id, {**state.to_doc(), "presence": "finished"})
        await self.repo.release(state.vehicle_id, state.instance_id)
        self.messages.emit_now(PresenceChanged(state.instance_id, state.vehicle_id, "finished"))
        self._unindex(state)
        self.messages.emit_now(StateWritten(state.instance_id, "instance"))
        await self.messages.emit(InstanceFinished(state.instance_id, state.vehicle_id, principal))
        await self.events.record(
            "instance",
            vehicle_id=state.vehicle_id,
            instance_id=state.instance_id,
            actor=principal,
            data={"action": "finished"},
        )

    # ---- background -----------------------------------------------------
    async def sweep(self, *, everything: bool = False) -> None:
        """Presence changes by age, and write back what changed (one record at a time)."""
        now = self.clock()
        states = list(self._by_id.values())
        for state in states:
            if state.polling:  # an open long poll is contact for as long as it is open
                self.touch(state)
        for state, presence in await self._changes(states, now):
            try:
                await self._change_presence(state, presence)
            except Unavailable as exc:
                self.dead_letters.failed("presence", exc)
                return
            except Exception as exc:
                await self.dead_letters.set_aside("presence", state.instance_id, exc, state)
                state.presence = presence  # not tried again every pass
        await self.write_back(everything=everything)

    async def write_back(self, *, everything: bool = False) -> None:
        """Write what moved: contact every ``contact_write_s`` (each instance a little
        sooner: ``contact_every_s``), the rest at once."""
        tick = time.monotonic()
        pacer = Pacer()
        due = [
            state
            for state in self._by_id.values()
            if state.dirty
            or (state.moved and (everything or tick - state.saved_at >= state.contact_every_s))
        ]
        for state in due:
            try:
                await self._write(state, tick, whole=state.dirty)
            except Unavailable as exc:
                self.dead_letters.failed("presence", exc)
                return
            except Exception as exc:
                await self.dead_letters.set_aside("presence", state.instance_id, exc, state)
                state.dirty = state.moved = False  # not tried again every pass
            await pacer.step()  # vehicles that connected together are due together

    async def _changes(
        self, states: list[InstanceState], now: datetime
    ) -> list[tuple[InstanceState, Presence]]:
        """The presence changes due, once the contact other replicas wrote is read back.

        With several replicas a copy is read back a little before it would change
        (``read_ahead_s``), so that it never looks stale here while the vehicle is in
        contact through another replica.
        """
        ahead = now + timedelta(seconds=self.settings.read_ahead_s)
        # Most vehicles are online and fresh: one comparison each, presence_of for the rest.
        fresh = online_since(ahead, self.settings.stale_after_s)
        near = [
            s
            for s in states
            if not (s.presence == "online" and s.last_seen is not None and s.last_seen >= fresh)
            and self._presence(s, ahead) != s.presence
        ]
        if not near:
            return []
        try:
            stored = await self.repo.get_many([s.instance_id for s in near])
        except Unavailable as exc:
            self.dead_letters.failed("presence", exc)
            return []
        by_id = {d["_id"]: d for d in stored}
        out = []
        for state in near:
            if (doc := by_id.get(state.instance_id)) is not None:
                state.merge_contact(doc)
                state.merge_presence(doc)
            if (presence := self._presence(state, now)) != state.presence:
                out.append((state, presence))
        return out

    async def _change_presence(self, state: InstanceState, presence: Presence) -> None:
        """Tell the change as the instance's next one, unless another replica told one under
        that number first: then this copy takes up the latest told, and the next sweep
        decides again from there (with the contact read back again)."""
        seq = state.presence_seq + 1
        if not await self.repo.claim_presence(state.instance_id, seq, presence, self.clock()):
            told = await self.repo.last_presence(state.instance_id)
            if told is not None and told["seq"] > state.presence_seq:
                state.presence, state.presence_seq = told["presence"], told["seq"]
            return  # another replica saw it first and told everyone
        state.presence, state.presence_seq = presence, seq
        self.messages.emit_now(PresenceChanged(state.instance_id, state.vehicle_id, presence))
        await self.events.record(
            "presence",
            vehicle_id=state.vehicle_id,
            instance_id=state.instance_id,
            data={"presence": presence},
        )
        await self.repo.note_presence(state.instance_id, seq, presence)
        self.messages.emit_now(StateWritten(state.instance_id, "instance"))

    async def _write(self, state: InstanceState, tick: float, *, whole: bool) -> None:
        fields = state.to_doc() if whole else state.contact_doc()
        fields.pop("finished_at", None)  # only finish writes it
        state.dirty = state.moved = False
        state.saved_at = tick
        await self.repo.save(state.instance_id, fields)
        if whole:
            self.messages.emit_now(StateWritten(state.instance_id, "instance"))

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

    def _adopt(self, doc: dict[str, Any]) -> InstanceState:
        """This replica's copy of a stored instance, caught up with ``doc``. An unfinished
        one is kept (it may be the vehicle's newest: an older copy of the vehicle goes)."""
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
        state.merge(doc)
        if state.finished:
            self._unindex(state)
        return state

    async def refresh(self, instance_id: str) -> bool:
        """Another replica changed the instance: catch up. Whether it is finished (or gone)."""
        doc = await self.repo.get(instance_id)
        if doc is None:
            if (gone := self._by_id.get(instance_id)) is not None:
                self._unindex(gone)
            return True
        if instance_id in self._by_id:
            self._adopt(doc)
        return doc.get("finished_at") is not None

    async def drop_finished_before(self, before: datetime) -> int:
        return await self.repo.drop_finished_before(before)
