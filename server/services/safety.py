"""Each vehicle's failsafe, and the watch on its telemetry: zone breaches, low battery.

**Failsafe policy.** An admin or the vehicle's field manager sets it
(``PUT /api/vehicles/{id}/failsafe``); until then the server's default applies
(version 0). The vehicle gets it with ``start_instance``, as a ``failsafe`` push on its
socket when it changes, or in ``get_control``'s answer while it has not acknowledged
the current version (``update_fbmessage.failsafe_version``).

**Watch.** Each new position of a live instance is held against the zones and the
battery threshold (:mod:`server.domain.watch`); a change is written by compare and set
(``watch``, one document per instance) and only the replica whose write lands records
its events: ``zone_breach`` / ``zone_cleared``, ``low_battery`` / ``battery_recovered``.
On a breach, a policy with ``on_breach`` makes the server send its action at once
(``stop``, ``keep_station``, or ``go_to`` home when the way there is clear). The first
position an instance reports is its home, unless the policy names one.

The check on the hot path reads nothing: the zones and the policies are read again
every ``tick`` (a second), the instance's watch state once when first needed.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable
from typing import Any, NamedTuple

from fleet_protocol import Alarm, EventKind, FailsafePolicy, SetFailsafe
from server.domain.access import Principal
from server.domain.alarms import alarms_of
from server.domain.arbitration import may_grant
from server.domain.clock import Clock, said_time
from server.domain.events import FailsafeChanged, SamplesStored
from server.domain.failsafe import breach_command, check_home
from server.domain.watch import WatchState, breach_data, change, dated, next_state
from server.errors import Conflict, Forbidden, NotFound
from server.services.auth import AuthService
from server.services.commands import CommandService
from server.services.events import EventService
from server.services.instances import InstanceService, InstanceState
from server.services.messagebus import MessageBus
from server.services.zones import ZoneService
from server.settings import Settings
from server.storage.backends import Doc
from server.storage.safety import SafetyRepo, watch_state

log = logging.getLogger("fleet.safety")


class StoredWatch(NamedTuple):
    """An instance's watch state and acknowledged failsafe version, as stored."""

    state: WatchState
    acked_version: int | None


#: Tries of a compare-and-set on a policy or a watch state other replicas change too.
_CAS_TRIES = 5


class SafetyService:
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
        #: The policies as this replica last read them (parsed once: the watch asks for
        #: one on every sample); a vehicle with none has the default.
        self._policies: dict[str, FailsafePolicy] = {}
        self._default = FailsafePolicy(
            after_s=settings.failsafe_after_s, action=settings.failsafe_action
        )
        #: instance id -> (its watch state, its home, the failsafe version it acknowledged)
        self._watch: dict[str, WatchState] = {}
        self._home: dict[str, tuple[float, float]] = {}
        self._acked: dict[str, int] = {}

    # ---- policies --------------------------------------------------------------------
    def _policy_of(self, doc: Doc | None) -> FailsafePolicy:
        if doc is None:
            return self._default
        return FailsafePolicy.model_validate(doc["policy"])

    async def policy(self, vehicle_id: str) -> FailsafePolicy:
        """The vehicle's policy as the store has it now."""
        policy = self._policy_of(await self.repo.policy(vehicle_id))
        if policy is self._default:
            self._policies.pop(vehicle_id, None)
        else:
            self._policies[vehicle_id] = policy
        return policy

    def known_policy(self, vehicle_id: str) -> FailsafePolicy:
        """The policy as this replica last read it (no store read)."""
        return self._policies.get(vehicle_id, self._default)

    async def view(self, principal: Principal, vehicle_id: str) -> dict[str, Any]:
        if not principal.can_see(vehicle_id) or await self.auth.vehicle_meta(vehicle_id) is None:
            raise NotFound(f"no vehicle {vehicle_id}")  # as an unknown one (docs/security.md)
        doc = await self.repo.policy(vehicle_id)
        policy = self._policy_of(doc)
        state = self.instances.current(vehicle_id) or await self.instances.current_or_latest(
            vehicle_id
        )
        acked = None
        if state is not None and not state.finished:
            watch = await self.repo.watch_of(state.instance_id)
            acked = (watch or {}).get("failsafe_version")
        return {
            "vehicle_id": vehicle_id,
            "failsafe": policy.model_dump(mode="json"),
            "acked_version": acked,
            "acked": None if state is None or state.finished else acked == policy.version,
            "updated_at": doc.get("updated_at") if doc else None,
            "updated_by": doc.get("updated_by") if doc else None,
        }

    async def set_policy(
        self, principal: Principal, vehicle_id: str, body: SetFailsafe
    ) -> dict[str, Any]:
        """Set the vehicle's whole policy (an admin, or a manager of the vehicle)."""
        if not principal.can_see(vehicle_id) or await self.auth.vehicle_meta(vehicle_id) is None:
            raise NotFound(f"no vehicle {vehicle_id}")
        if not may_grant(principal, vehicle_id):
            raise Forbidden(
                f"only a manager of vehicle {vehicle_id}, or an admin, sets its failsafe"
            )
        if body.home is not None:
            check_home(self.zones.known(), vehicle_id, (body.home.lat, body.home.lon))
        for _ in range(_CAS_TRIES):
            current = await self.repo.policy(vehicle_id)
            version = int(current["version"]) if current else 0
            policy = FailsafePolicy(
                after_s=body.after_s
                if body.after_s is not None
                else self.settings.failsafe_after_s,
                action=body.action or self.settings.failsafe_action,
                home=body.home,
                on_breach=body.on_breach,
                low_battery_pct=body.low_battery_pct,
                version=version + 1,
            )
            doc = {
                "vehicle_id": vehicle_id,
                "version": version + 1,
                "policy": policy.model_dump(mode="json"),
                "updated_at": self.clock(),
                "updated_by": principal.name,
            }
            if await self.repo.put_policy(doc, version):
                break
        else:
            raise Conflict("the failsafe of this vehicle keeps changing; try again")
        self._policies[vehicle_id] = policy
        wire = policy.model_dump(mode="json")
        await self.events.record(
            "failsafe_changed", vehicle_id=vehicle_id, actor=principal, data=wire
        )
        self.messages.emit_now(FailsafeChanged(vehicle_id, wire))
        return await self.view(principal, vehicle_id)

    async def for_start(self, state: InstanceState) -> FailsafePolicy:
        """The policy a starting instance gets (read from the store: it may have changed).
        What this replica kept of the instance is forgotten: it may have been on another
        replica since, whose changes are in the store (read again at its next sample)."""
        self.forget(state.instance_id)
        return await self.policy(state.vehicle_id)

    async def pending(self, state: InstanceState) -> FailsafePolicy | None:
        """The policy, when the instance has not acknowledged its version yet."""
        policy = self.known_policy(state.vehicle_id)
        acked = self._acked.get(state.instance_id)
        if acked is None:
            watch = await self.repo.watch_of(state.instance_id)
            acked = int((watch or {}).get("failsafe_version", -1))
            if acked >= 0:
                self._acked[state.instance_id] = acked
        return policy if acked != policy.version else None

    async def acknowledge(self, state: InstanceState, version: int | None) -> None:
        """The instance applies this version of its policy now. A version the server has
        not issued (yet) is not taken: the vehicle cannot apply what it was never told
        (an agent that kept a number from another server), and taking it would show a
        later policy as applied."""
        if version is None or self._acked.get(state.instance_id) == version:
            return
        if version > self.known_policy(state.vehicle_id).version and (
            version > (await self.policy(state.vehicle_id)).version
        ):
            log.warning(
                "%s: failsafe version %d acknowledged, never issued: not taken",
                state.vehicle_id,
                version,
            )
            return
        self._acked[state.instance_id] = version
        await self.repo.ack_failsafe(state.instance_id, state.vehicle_id, version)
        await self.events.record(
            "failsafe_acked",
            vehicle_id=state.vehicle_id,
            instance_id=state.instance_id,
            data={"version": version},
        )

    def acked(self, state: InstanceState) -> bool | None:
        """Whether the instance applies the current version (None: not known here)."""
        return self.acked_version(state, self._acked.get(state.instance_id))

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

    def acked_version(self, state: InstanceState, version: int | None) -> bool | None:
        """Whether ``version`` (the one the instance acknowledged) is the policy's now."""
        if version is None:
            return None
        return version == self.known_policy(state.vehicle_id).version

    # ---- background: read again what the hot path uses ---------------------------------
    async def tick(self) -> None:
        await self.zones.current()
        docs = await self.repo.policies()
        policies: dict[str, FailsafePolicy] = {}
        for vehicle_id, doc in docs.items():
            kept = self._policies.get(vehicle_id)  # parsed again only when its version moved
            same = kept is not None and kept.version == doc.get("version")
            policies[vehicle_id] = kept if kept is not None and same else self._policy_of(doc)
        self._policies = policies

    # ---- the watch --------------------------------------------------------------------
    def on_samples(self, event: SamplesStored) -> Awaitable[None] | None:
        """Hold the newest position of the batch against the zones and the battery."""
        sample = None
        for s, late in zip(event.samples, event.replayed, strict=True):
            if not late and (sample is None or s.ts >= sample.ts):
                sample = s
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
        for _ in range(_CAS_TRIES):
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
        self._watch.pop(instance_id, None)
        self._home.pop(instance_id, None)
        self._acked.pop(instance_id, None)
