"""The watch on each vehicle's telemetry: zone breaches, low battery, and the failsafe's
action on a breach.

Each new position of a live instance is held against the zones and the
battery threshold (:mod:`server.domain.watch`); a change is written by compare and set
(``watch``, one document per instance) and only the replica whose write lands records
its events: ``zone_breach`` / ``zone_cleared``, ``low_battery`` / ``battery_recovered``.
On a breach, a policy with ``on_breach`` makes the server send its action at once
(:func:`~server.domain.failsafe.breach_command`: ``stop``, ``keep_station``, or
``go_to`` home when the way there is clear). The first position an instance reports is
its home, unless the policy names one. The policies themselves (set, sent,
acknowledged) are :class:`~server.services.failsafe_policies.FailsafePolicies`, this
service's base.

The check on the hot path reads nothing: the zones and the policies are read again
every ``tick`` (a second), the instance's watch state once when first needed.

Alarms say what is wrong now, so a change of the rules is judged at once too: when the
zones or a vehicle's battery threshold moved since the watch last judged by them
(:meth:`SafetyService.judge_again`: a zone changed here or a policy set here, another
replica's change heard on the bus, or the tick's reading), each unfinished instance they
touch is judged again against its latest position as the store and this replica have
it, a vehicle that stopped reporting too. The same compare and set records what changed,
once of all replicas (``reason`` in the event's data: ``zones_changed`` or
``failsafe_changed``). A replica judges by the rules as it last read them: a stored
state names the rules it was judged by, and one judged by newer rules than this
replica's is not written over (that would bring back an alarm the newer rules ended);
the instance is judged again once the rules are read here. Each write of a watch state
is announced
(:class:`~server.domain.events.StateWritten`, part ``watch``), so that a replica that
kept a copy of it reads it again.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable
from typing import Any, NamedTuple

from fleet_protocol import Alarm, EventKind, FailsafePolicy
from server.domain.alarms import alarms_of
from server.domain.clock import Clock, said_time
from server.domain.events import FailsafeChanged, SamplesStored, StateWritten, ZonesChanged
from server.domain.failsafe import breach_command
from server.domain.watch import (
    Judged,
    JudgedBy,
    Rules,
    WatchState,
    battery_event,
    behind,
    breach_data,
    change,
    cleared_data,
    dated,
)
from server.domain.zones import ZoneSet
from server.services.auth import AuthService
from server.services.commands import CommandService
from server.services.events import EventService
from server.services.failsafe_policies import CAS_TRIES, FailsafePolicies
from server.services.instances import InstanceService, InstanceState
from server.services.messagebus import MessageBus
from server.services.zones import ZoneService
from server.settings import Settings
from server.storage.backends import Doc
from server.storage.safety import SafetyRepo, judged_by, watch_state


class StoredWatch(NamedTuple):
    """An instance's watch state and acknowledged failsafe version, as stored."""

    state: WatchState
    acked_version: int | None


class SafetyService(FailsafePolicies):
    """The watch (see the module) on the failsafe policies of
    :class:`~server.services.failsafe_policies.FailsafePolicies`."""

    def __init__(
        self,
        settings: Settings,
        repo: SafetyRepo,
        instances: InstanceService,
        auth: AuthService,
        zones: ZoneService,
        commands: CommandService,
        events: EventService,
        messages: MessageBus,
        clock: Clock,
    ) -> None:
        self.settings = settings
        self.repo = repo
        self.instances = instances
        self.auth = auth
        self.zones = zones
        self.commands = commands
        self.events = events
        self.messages = messages
        self.clock = clock
        # The policies' (what FailsafePolicies keeps: its attributes say what each is).
        self._policies: dict[str, FailsafePolicy] = {}
        self._default = FailsafePolicy(
            after_s=settings.failsafe_after_s, action=settings.failsafe_action
        )
        self._acked: dict[str, int] = {}
        #: instance id -> its watch state, and its home
        self._watch: dict[str, WatchState] = {}
        #: Each instance's judgements one at a time, in the order their samples came (an
        #: older one finished last undid a newer one's alarm: :meth:`_in_turn`).
        self._turns: dict[str, asyncio.Lock] = {}
        self._home: dict[str, tuple[float, float]] = {}
        #: The rules the watch last judged every instance by, and those before (a zone
        #: gone since is named by them); None until first read.
        self._rules: Rules | None = None
        self._former: ZoneSet = ZoneSet()
        #: Instances whose stored state was judged by newer rules than this replica's:
        #: judged again at the next reading of the rules.
        self._behind: set[str] = set()
        self._judging = asyncio.Lock()

    # ---- what is wrong with a vehicle now ----------------------------------------------
    def alarms(self, state: InstanceState, watch: WatchState | None = None) -> list[Alarm]:
        """The instance's alarms (:func:`~server.domain.alarms.alarms_of`): ``watch`` as the
        store has it (None: as this replica last saw it, nothing when it has not)."""
        policy = self.known_policy(state.vehicle_id)
        in_failsafe = policy.action if state.control_mode == "failsafe" else None
        entered = state.control_mode_since
        watch = watch if watch is not None else self._watch.get(state.instance_id)
        if watch is None:
            return alarms_of(in_failsafe, (), None, entered)
        zones = [
            (
                breach_data(self.zones.known(), state.vehicle_id, z, entered=True),
                watch.breach_since.get(z),
            )
            for z in sorted(watch.breaches)
        ]
        pct = (state.position or {}).get("battery_pct")
        reading = float(pct) if isinstance(pct, int | float) else None
        return alarms_of(
            in_failsafe,
            [(z["zone_kind"], z["zone"], z["zone_id"], since) for z, since in zones],
            (reading, policy.low_battery_pct, watch.battery_since) if watch.low_battery else None,
            entered,
        )

    def watches_here(self, state: InstanceState) -> bool:
        """Whether this replica holds the instance's watch state (it took its positions)."""
        return state.instance_id in self._watch

    async def watches(self, instance_ids: list[str]) -> dict[str, StoredWatch]:
        """The watch state of each of these instances and the failsafe version it applies,
        as the store has them (one read): the same on every replica."""
        docs = await self.repo.watches_of(instance_ids)
        return {
            str(doc["_id"]): StoredWatch(
                watch_state(doc),
                int(doc["failsafe_version"]) if doc.get("failsafe_version") is not None else None,
            )
            for doc in docs
        }

    # ---- the watch --------------------------------------------------------------------
    def on_samples(self, event: SamplesStored) -> Awaitable[None] | None:
        """Hold the batch's sample that became the vehicle's latest position against the
        zones and the battery: none when it came late, or is dated too far ahead to be
        the position (a clock glitch), which would otherwise raise alarms and act on a
        place and a reading the vehicle does not report now."""
        sample = event.current
        if sample is None:
            return None
        state = self.instances.current(event.vehicle_id)
        if state is None or state.finished:
            return None
        was = self._watch.get(state.instance_id)
        judged, by = self._judged(state, sample), self._by(state.vehicle_id)
        turn = self._turns.get(state.instance_id)
        if was is not None and (turn is None or not turn.locked()):
            now = by.next(was, state.vehicle_id, judged)
            if now is was or now == was:
                return None  # most samples: nothing changes, nothing waits
        return self._in_turn(state, judged, by)

    async def _in_turn(self, state: InstanceState, judged: Judged, by: JudgedBy) -> None:
        """One sample's judgement, after those of the samples before it (a lock per
        instance: its waiters go in the order they came)."""
        turn = self._turns.setdefault(state.instance_id, asyncio.Lock())
        async with turn:
            was = self._watch.get(state.instance_id)
            if was is None:
                await self._first(state, judged, by)
            elif by.next(was, state.vehicle_id, judged) != was:
                await self._record(state, judged, by)

    def _by(self, vehicle_id: str) -> JudgedBy:
        return JudgedBy(self.zones.known(), self.known_policy(vehicle_id))

    def _judged(self, state: InstanceState, sample: Doc) -> Judged:
        at = said_time(sample["ts"], self.clock(), state.started_at)
        pct = sample.get("battery_pct")
        reading = float(pct) if isinstance(pct, int | float) else None
        return Judged(float(sample["lat"]), float(sample["lon"]), reading, at)

    async def _first(self, state: InstanceState, judged: Judged, by: JudgedBy) -> None:
        """The instance's watch state, read (or begun, with its home) once."""
        doc = await self.repo.watch_of(state.instance_id)
        if doc is None:
            await self.repo.begin_watch(state.instance_id, state.vehicle_id, judged.point)
            doc = await self.repo.watch_of(state.instance_id)
        was = watch_state(doc)
        self._watch[state.instance_id] = was
        if doc is not None and doc.get("home"):
            self._home[state.instance_id] = (doc["home"]["lat"], doc["home"]["lon"])
        if doc is not None and doc.get("failsafe_version") is not None:
            self._acked[state.instance_id] = int(doc["failsafe_version"])
        if by.next(was, state.vehicle_id, judged) != was:
            await self._record(state, judged, by)

    async def _record(
        self, state: InstanceState, judged: Judged, by: JudgedBy, *, keep: bool = True
    ) -> None:
        """Judge the stored state by ``by`` and write the next one if it moved (compare
        and set), each new alarm dated ``judged.at``; record what changed. A state judged
        by newer rules than ``by`` is left as it is: the instance is judged again once
        this replica has read them (:meth:`judge_again`). ``keep``: this replica keeps
        the state as its copy (it takes the instance's samples)."""
        for _ in range(CAS_TRIES):
            doc = await self.repo.watch_of(state.instance_id)
            stored, stored_by = watch_state(doc), judged_by(doc)
            if behind(by.seen, stored_by):
                self._behind.add(state.instance_id)
                return
            now = by.next(stored, state.vehicle_id, judged)
            moved = change(stored, now)
            rev = int(doc["rev"]) if doc is not None else None
            if not moved:
                if doc is not None and by.seen != stored_by:
                    # Said by the newer rules: older ones may not undo it.
                    await self.repo.move_watch(
                        state.instance_id, state.vehicle_id, rev, stored, by.seen
                    )
                if keep or state.instance_id in self._watch:
                    self._watch[state.instance_id] = stored  # another replica recorded it
                return
            now = dated(stored, now, judged.at)
            if await self.repo.move_watch(state.instance_id, state.vehicle_id, rev, now, by.seen):
                break
        else:
            return
        if keep or state.instance_id in self._watch:
            self._watch[state.instance_id] = now
        self.messages.emit_now(StateWritten(state.instance_id, "watch"))
        zones = by.zones
        where: dict[str, Any] = {"lat": judged.lat, "lon": judged.lon}
        zone_where = {**where, "reason": "zones_changed"} if judged.zones_moved else where
        for zone_id in sorted(moved.entered):
            data = {**breach_data(zones, state.vehicle_id, zone_id, entered=True), **zone_where}
            action = await self._act_on_breach(state, zone_id, data)
            await self._event("zone_breach", state, {**data, **action})
        named_by = [zones, *(r.zones for r in (self._rules,) if r is not None), self._former]
        for zone_id in sorted(moved.left):
            data = {**cleared_data(named_by, state.vehicle_id, zone_id), **zone_where}
            await self._event("zone_cleared", state, data)
        if moved.battery is not None:
            threshold = by.policy.low_battery_pct
            kind = battery_event(
                moved.battery, judged.battery_pct, threshold, rule=judged.threshold_moved
            )
            data = {"battery_pct": judged.battery_pct, "threshold_pct": threshold, **where}
            if judged.threshold_moved:
                data["reason"] = "failsafe_changed"
            await self._event(kind, state, data)

    async def _act_on_breach(
        self, state: InstanceState, zone_id: str, data: dict[str, Any]
    ) -> dict[str, Any]:
        """The policy's action on a breach, when it asks for one: the command sent."""
        policy = self.known_policy(state.vehicle_id)
        if not policy.on_breach or policy.action == "none":
            return {}
        why = f"failsafe on breach: {data['message']}"
        kind, args = breach_command(
            policy,
            self.zones.known(),
            state.vehicle_id,
            state.capabilities,
            state.position,
            self._home.get(state.instance_id),
        )
        cmd = await self.commands.system_command(state, kind, args, why)
        return {"action": policy.action, "command_id": cmd.command_id, "command_type": kind}

    async def _event(self, kind: EventKind, state: InstanceState, data: dict[str, Any]) -> None:
        await self.events.record(
            kind, vehicle_id=state.vehicle_id, instance_id=state.instance_id, data=data
        )

    # ---- the rules moved: judge again -------------------------------------------------
    async def tick(self) -> None:
        """The zones and the policies read again; judged again when they moved."""
        await super().tick()
        await self.judge_again()

    def _rules_now(self) -> Rules:
        thresholds = {v: p.low_battery_pct for v, p in self._policies.items()}
        return Rules(self.zones.known(), thresholds)

    def _threshold(self, rules: Rules, vehicle_id: str) -> float | None:
        return rules.thresholds.get(vehicle_id, self._default.low_battery_pct)

    def on_zones_changed(self, _event: ZonesChanged) -> Awaitable[None]:
        """A zone changed here (the set read again already): judge again."""
        return self.judge_again()

    def on_failsafe_changed(self, event: FailsafeChanged) -> Awaitable[None]:
        """A policy set here (kept already): judge again."""
        return self.judge_again()

    async def rules_again(self) -> None:
        """Another replica changed the zones: read them, and judge again."""
        await self.zones.current()
        await self.judge_again()

    async def judge_again(self) -> None:
        """Judge each unfinished instance whose rules moved since the watch last judged by
        them (the zones: every one; a threshold: its vehicle's) against its latest
        position, as the store and this replica have it. The first call only notes the
        rules (nothing was judged before)."""
        async with self._judging:
            rules, was = self._rules_now(), self._rules
            zones_moved = was is not None and rules.zones.version != was.zones.version
            vehicles = set()
            if was is not None:
                vehicles = {
                    v
                    for v in rules.thresholds.keys() | was.thresholds.keys()
                    if self._threshold(rules, v) != self._threshold(was, v)
                }
            pending, self._behind = self._behind, set()
            if zones_moved or vehicles or pending:
                # A failure (the store away) leaves the rules as they were: the next tick
                # judges again. Meanwhile a zone gone is named by ``self._rules``.
                try:
                    for state in await self.instances.everyone():
                        threshold_moved = state.vehicle_id in vehicles
                        if zones_moved or threshold_moved or state.instance_id in pending:
                            await self._again(state, zones_moved, threshold_moved)
                except BaseException:
                    self._behind |= pending
                    raise
            if was is not None and zones_moved:
                self._former = was.zones
            self._rules = rules

    async def _again(self, state: InstanceState, zones_moved: bool, threshold_moved: bool) -> None:
        """One instance judged again by the rules now (see :meth:`judge_again`): they
        moved, or a judgement by older ones was not written."""
        position = state.position
        if position is None:
            return  # no position: nothing was judged, nothing is
        pct = position.get("battery_pct")
        reading = float(pct) if isinstance(pct, int | float) else None
        point = (float(position["lat"]), float(position["lon"]))
        now = self.clock()
        # A new alarm is dated when the rule changed, or else by the sample it came from.
        at = (
            now
            if zones_moved or threshold_moved or "ts" not in position
            else said_time(position["ts"], now, state.started_at)
        )
        judged = Judged(*point, reading, at, zones_moved, threshold_moved)
        turn = self._turns.setdefault(state.instance_id, asyncio.Lock())
        async with turn:  # not between a sample's reading and writing of the state
            await self._record(state, judged, self._by(state.vehicle_id), keep=False)

    def forget_watch(self, instance_id: str) -> None:
        """Another replica wrote the instance's watch state: the copy here is read again
        at its next sample."""
        self._watch.pop(instance_id, None)

    def forget(self, instance_id: str) -> None:
        """Its watch state and home too (read again at its next sample)."""
        self._watch.pop(instance_id, None)
        self._home.pop(instance_id, None)
        turn = self._turns.get(instance_id)
        if turn is not None and not turn.locked():
            del self._turns[instance_id]
        super().forget(instance_id)
