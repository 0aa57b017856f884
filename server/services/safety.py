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
"""

from __future__ import annotations

from collections.abc import Awaitable
from typing import Any, NamedTuple

from fleet_protocol import Alarm, EventKind, FailsafePolicy
from server.domain.alarms import alarms_of
from server.domain.clock import Clock, said_time
from server.domain.events import SamplesStored
from server.domain.failsafe import breach_command
from server.domain.watch import WatchState, breach_data, change, dated, next_state
from server.services.auth import AuthService
from server.services.commands import CommandService
from server.services.events import EventService
from server.services.failsafe_policies import CAS_TRIES, FailsafePolicies
from server.services.instances import InstanceService, InstanceState
from server.services.messagebus import MessageBus
from server.services.zones import ZoneService
from server.settings import Settings
from server.storage.safety import SafetyRepo, watch_state


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
        self._home: dict[str, tuple[float, float]] = {}

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
        if was is None:
            return self._first(state, sample)
        now = self._next(state, was, sample)
        return None if now is was or now == was else self._record(state, sample, now)

    def _next(self, state: InstanceState, was: WatchState, sample: Any) -> WatchState:
        threshold = self.known_policy(state.vehicle_id).low_battery_pct
        point = (float(sample.lat), float(sample.lon))
        return next_state(
            was, self.zones.known(), state.vehicle_id, point, sample.battery_pct, threshold
        )

    async def _first(self, state: InstanceState, sample: Any) -> None:
        """The instance's watch state, read (or begun, with its home) once."""
        doc = await self.repo.watch_of(state.instance_id)
        if doc is None:
            home = (float(sample.lat), float(sample.lon))
            await self.repo.begin_watch(state.instance_id, state.vehicle_id, home)
            doc = await self.repo.watch_of(state.instance_id)
        was = watch_state(doc)
        self._watch[state.instance_id] = was
        if doc is not None and doc.get("home"):
            self._home[state.instance_id] = (doc["home"]["lat"], doc["home"]["lon"])
        if doc is not None and doc.get("failsafe_version") is not None:
            self._acked[state.instance_id] = int(doc["failsafe_version"])
        now = self._next(state, was, sample)
        if now != was:
            await self._record(state, sample, now)

    async def _record(self, state: InstanceState, sample: Any, now: WatchState) -> None:
        """Write the new state if it is still news (compare and set), each new alarm dated
        by the sample that raised it; record what changed."""
        at = said_time(sample.ts, self.clock(), state.started_at)
        for _ in range(CAS_TRIES):
            doc = await self.repo.watch_of(state.instance_id)
            stored = watch_state(doc)
            moved = change(stored, now)
            if not moved:
                self._watch[state.instance_id] = stored  # another replica recorded it
                return
            now = dated(stored, now, at)
            rev = int(doc["rev"]) if doc is not None else None
            if await self.repo.move_watch(state.instance_id, state.vehicle_id, rev, now):
                break
        else:
            return
        self._watch[state.instance_id] = now
        where = {"lat": float(sample.lat), "lon": float(sample.lon)}
        for zone_id in sorted(moved.entered):
            data = {
                **breach_data(self.zones.known(), state.vehicle_id, zone_id, entered=True),
                **where,
            }
            action = await self._act_on_breach(state, zone_id, data)
            await self._event("zone_breach", state, {**data, **action})
        for zone_id in sorted(moved.left):
            data = {
                **breach_data(self.zones.known(), state.vehicle_id, zone_id, entered=False),
                **where,
            }
            await self._event("zone_cleared", state, data)
        if moved.battery is not None:
            kind: EventKind = "low_battery" if moved.battery == "low" else "battery_recovered"
            threshold = self.known_policy(state.vehicle_id).low_battery_pct
            data = {"battery_pct": sample.battery_pct, "threshold_pct": threshold, **where}
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

    def forget(self, instance_id: str) -> None:
        """Its watch state and home too (read again at its next sample)."""
        self._watch.pop(instance_id, None)
        self._home.pop(instance_id, None)
        super().forget(instance_id)
