"""Each vehicle's failsafe policy: set, read, sent, acknowledged.

An admin or the vehicle's field manager sets it
(``PUT /api/vehicles/{id}/failsafe``, by compare and set on its version); until
then the server's default applies (version 0). The vehicle gets it with
``start_instance``, as a ``failsafe`` push on its socket when it changes, or in
``get_control``'s answer while it has not acknowledged the current version
(``update_fbmessage.failsafe_version``). The policies are read again every
``tick`` (a second), so that the watch on each sample
(:class:`~server.services.safety.SafetyService`, built on this) reads nothing.
"""

from __future__ import annotations

import logging
from typing import Any

from fleet_protocol import FailsafePolicy, SetFailsafe
from server.domain.access import Principal
from server.domain.arbitration import may_grant
from server.domain.clock import Clock
from server.domain.events import FailsafeChanged
from server.domain.failsafe import check_home
from server.errors import Conflict, Forbidden, NotFound
from server.services.auth import AuthService
from server.services.events import EventService
from server.services.instances import InstanceService, InstanceState
from server.services.messagebus import MessageBus
from server.services.zones import ZoneService
from server.settings import Settings
from server.storage.backends import Doc
from server.storage.safety import SafetyRepo

__all__ = ["CAS_TRIES", "FailsafePolicies"]

log = logging.getLogger("fleet.safety")

#: Tries of a compare-and-set on a policy or a watch state other replicas change too.
CAS_TRIES = 5


class FailsafePolicies:
    """The policies' side of :class:`~server.services.safety.SafetyService` (its base;
    built as it is)."""

    settings: Settings
    repo: SafetyRepo
    #: Whose vehicles there are (``vehicle_meta``), and their instances.
    auth: AuthService
    instances: InstanceService
    #: The zones a home is held against (as this replica last read them).
    zones: ZoneService
    events: EventService
    messages: MessageBus
    clock: Clock
    #: The policies as this replica last read them (parsed once: the watch asks for
    #: one on every sample); a vehicle with none has ``_default``.
    _policies: dict[str, FailsafePolicy]
    _default: FailsafePolicy
    #: instance id -> the failsafe version it acknowledged
    _acked: dict[str, int]

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
        for _ in range(CAS_TRIES):
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
        # Awaited, as a zone's change is: the answer comes once the vehicle's alarms are
        # judged by the new policy (a sample sent after it is judged after that).
        await self.messages.emit(FailsafeChanged(vehicle_id, wire))
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

    def acked_version(self, state: InstanceState, version: int | None) -> bool | None:
        """Whether ``version`` (the one the instance acknowledged) is the policy's now."""
        if version is None:
            return None
        return version == self.known_policy(state.vehicle_id).version

    # ---- background: read again what the hot path uses ---------------------------------
    async def tick(self) -> None:
        """The zones and the policies read again, so that the watch on each sample reads
        neither from the store."""
        await self.zones.current()
        docs = await self.repo.policies()
        policies: dict[str, FailsafePolicy] = {}
        for vehicle_id, doc in docs.items():
            kept = self._policies.get(vehicle_id)  # parsed again only when its version moved
            same = kept is not None and kept.version == doc.get("version")
            policies[vehicle_id] = kept if kept is not None and same else self._policy_of(doc)
        self._policies = policies

    def forget(self, instance_id: str) -> None:
        """What this replica kept of the instance is dropped (read again when needed)."""
        self._acked.pop(instance_id, None)
