"""Instances and presence: start (or resume), heartbeat, finish, parameters.

The store holds every instance; this replica keeps a copy of the unfinished
ones it deals with (:class:`InstanceState`; the copies and the lookups on them
are :class:`~server.services.instance_copies.InstanceCopies`, this service's
base). Contact and the latest position move with every frame of every
vehicle, so they live in the copy and are written back by
:meth:`InstanceService.sweep` every ``contact_write_s``; parameters are
written back at the next sweep; a change of control mode and a finish are
written at once (decisions depend on them). Before a presence change is
declared, the contact other replicas wrote is read back, and of several
replicas seeing it only one tells it: a change is told under the instance's
next number (``presence_seq``), and the store keeps one change per number
(its key), so the first to insert it tells it. One replica or several, the
algorithm is this one.
"""

from __future__ import annotations

import math
import secrets
import time
from datetime import datetime, timedelta
from typing import Any

from fleet_protocol import PatchVehicle, StartInstance, format_ts
from server.domain.access import Principal
from server.domain.clock import Clock
from server.domain.events import InstanceFinished, PresenceChanged, StateWritten
from server.domain.params import params_after
from server.domain.presence import Presence, online_since
from server.errors import Conflict, Forbidden, NotFound, Unavailable
from server.services.auth import AuthService
from server.services.dead_letters import DeadLetters
from server.services.events import EventService
from server.services.instance_copies import InstanceCopies
from server.services.instance_state import InstanceState
from server.services.messagebus import MessageBus
from server.services.pacing import Pacer
from server.settings import Settings
from server.storage.instances import InstancesRepo

__all__ = ["InstanceService", "InstanceState"]

#: Tries to claim a vehicle's instance while other replicas claim and finish it.
_CLAIM_TRIES = 5


class InstanceService(InstanceCopies):
    """The life of an instance (see the module), on this replica's copies
    (:class:`~server.services.instance_copies.InstanceCopies`)."""

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
        super().__init__(settings, repo, clock)
        self.auth = auth
        self.events = events
        self.messages = messages
        self.dead_letters = dead_letters

    # ---- vehicle side ---------------------------------------------------
    async def start(self, principal: Principal, body: StartInstance) -> tuple[InstanceState, bool]:
        if not principal.acts_for(body.vehicle_id):
            said = f"this token does not act for vehicle {body.vehicle_id}"
            raise Forbidden(said, details=[{"field": "vehicle_id", "message": said}])
        meta = await self.auth.vehicle_meta(body.vehicle_id)
        if meta is None:
            raise NotFound(f"no vehicle {body.vehicle_id}; an admin registers it first")
        state, created = await self._claimed(body, meta)
        resumed = not created
        renamed = False
        if resumed:
            shown = (state.name, state.vehicle_type)
            if body.name:
                state.name = body.name
            if body.vehicle_type:
                state.vehicle_type = body.vehicle_type
            renamed = (state.name, state.vehicle_type) != shown
            if body.capabilities is not None:
                state.capabilities = list(body.capabilities)
            self.merge_params(state, body.params, starting=True)
            await self._write(state, time.monotonic(), whole=True, naming=True)
        if not resumed or renamed:
            # from offline or finished (the vehicle's last instance), or under a new name
            # or type: fleet watchers hear of it
            self.messages.emit_now(PresenceChanged(state.instance_id, state.vehicle_id, "online"))
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
                read_at = time.monotonic()
                doc = await self.repo.get(current)
                if doc is not None and doc.get("finished_at") is None:
                    return self._adopt(doc, read_at), False
                await self.repo.release(vehicle_id, current)  # a claim left by a crash
                continue
            # A new instance goes on from the vehicle's last one: the name, type and
            # capabilities its last start gave (else the registered name and type, and
            # no capabilities), and its latest position.
            last = await self.repo.latest_for_vehicle(vehicle_id) or {}
            now = self.clock()
            state = InstanceState(
                instance_id="i-" + secrets.token_hex(8),
                vehicle_id=vehicle_id,
                name=body.name or last.get("name") or meta.get("name") or vehicle_id,
                vehicle_type=(
                    body.vehicle_type
                    or last.get("vehicle_type")
                    or meta.get("vehicle_type")
                    or "usv"
                ),
                capabilities=list(
                    body.capabilities
                    if body.capabilities is not None
                    else last.get("capabilities") or []
                ),
                started_at=now,
                params=dict(body.params),
                params_updated_at=now if body.params else None,
                last_seen=now,
                presence="online",
                position=last.get("position"),
            )
            if not await self.repo.claim(vehicle_id, state.instance_id):
                continue  # another replica started one at the same moment: take it up
            await self.repo.insert({**state.to_doc(), "presence": "online", "presence_seq": 0})
            self._index(state)
            self.messages.emit_now(StateWritten(state.instance_id, "instance"))
            return state, True
        raise Conflict(f"vehicle {vehicle_id}'s instance keeps changing; try again")

    async def change_vehicle(
        self, principal: Principal, vehicle_id: str, body: PatchVehicle
    ) -> None:
        """An admin puts a vehicle's name or type right: in its record, and in its current
        (or latest) instance, which the fleet shows and the vehicle's next instance goes on
        from (a name or type its next start announces still wins). Recorded as a
        ``vehicle_changed`` event with what was there before."""
        fields: dict[str, Any] = body.model_dump(exclude_none=True)
        former = await self.auth.change_vehicle(vehicle_id, fields)
        state = await self.current_or_latest(vehicle_id)
        was = {
            "name": state.name if state is not None else former.get("name"),
            "vehicle_type": state.vehicle_type if state is not None else former.get("vehicle_type"),
        }
        changed = {k: v for k, v in fields.items() if was.get(k) != v}
        if not changed:
            return
        if state is not None:
            await self.repo.save(state.instance_id, changed)  # these fields alone
            # Into the copy once written: a refresh that read the store before then does
            # not put the former name back (``InstanceState.merge``).
            state.name = changed.get("name", state.name)
            state.vehicle_type = changed.get("vehicle_type", state.vehicle_type)
            state.named_at = time.monotonic()
            self.messages.emit_now(StateWritten(state.instance_id, "instance"))
        await self.events.record(
            "vehicle_changed",
            vehicle_id=vehicle_id,
            instance_id=state.instance_id if state is not None else None,
            actor=principal,
            data={**changed, "was": {k: was[k] for k in changed}},
        )

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

    def set_position(self, state: InstanceState, doc: dict[str, Any]) -> bool:
        """Keep the sample with the greatest ``ts`` as the latest position (``doc``: the
        sample in its stored form, ``model_dump(exclude_none=True)``; copied)."""
        current = state.position
        if current is not None and current["ts"] >= doc["ts"]:
            return False
        state.position = dict(doc)
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
        self.touch(state, state.finished_at)  # the call is contact too (last_seen moves)
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
            # when it was last heard: a change found late (the server was down meanwhile)
            # is dated when found, and this says since when it was silent
            data={"presence": presence}
            | (
                {"last_seen": format_ts(state.last_seen)}
                if presence in ("stale", "offline") and state.last_seen is not None
                else {}
            ),
        )
        await self.repo.note_presence(state.instance_id, seq, presence)
        self.messages.emit_now(StateWritten(state.instance_id, "instance"))

    async def _write(
        self, state: InstanceState, tick: float, *, whole: bool, naming: bool = False
    ) -> None:
        """The instance's record: the fields that move with contact, or ``whole``. Its
        name and type only when ``naming`` (the vehicle's own start announced them): an
        admin's change of them, made on any replica, is not written back over."""
        fields = state.to_doc() if whole else state.contact_doc()
        fields.pop("finished_at", None)  # only finish writes it
        if not naming:
            fields.pop("name", None)
            fields.pop("vehicle_type", None)
        state.dirty = state.moved = False
        state.saved_at = tick
        if whole:
            state.written_at = math.inf  # a read begun now may not see it
        try:
            await self.repo.save(state.instance_id, fields)
        except BaseException:
            # Not written: written again at the next pass (the store away), unless the
            # caller sets the record aside.
            state.dirty = state.dirty or whole
            state.moved = True
            raise
        finally:
            if whole:
                state.written_at = time.monotonic()
        if whole:
            self.messages.emit_now(StateWritten(state.instance_id, "instance"))

    async def drop_finished_before(self, before: datetime) -> int:
        return await self.repo.drop_finished_before(before)
