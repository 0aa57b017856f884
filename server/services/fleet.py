"""What operators read about the fleet: vehicles, instances, parameters, events."""

from __future__ import annotations

from typing import Any

from fleet_protocol import ConnectInstance, GetParamResult, InstanceView, Sample, VehicleView
from server.domain.access import Principal
from server.domain.watch import WatchState
from server.errors import NotFound
from server.services.auth import AuthService
from server.services.instances import InstanceService, InstanceState
from server.services.link import Leases
from server.services.safety import SafetyService, StoredWatch


class FleetViews:
    def __init__(
        self,
        auth: AuthService,
        instances: InstanceService,
        leases: Leases,
        safety: SafetyService,
    ) -> None:
        self.auth = auth
        self.instances = instances
        self.leases = leases
        self.safety = safety

    def instance_view(self, state: InstanceState) -> InstanceView:
        return InstanceView(
            instance_id=state.instance_id,
            vehicle_id=state.vehicle_id,
            name=state.name,
            vehicle_type=state.vehicle_type,
            capabilities=state.capabilities,
            presence=self.instances.presence(state),
            last_seen=state.last_seen,
            control_mode=state.control_mode,
            control=self.leases.lease_info(state.instance_id),
            started_at=state.started_at,
        )

    def live_view(self, state: InstanceState, *, alarms: bool = True) -> dict[str, Any]:
        """The view of a vehicle from its instance alone (no store read), as JSON for a
        push; without ``alarms`` when not asked for, or when this replica does not hold
        the vehicle's watch state (another takes its positions): a push must not clear
        alarms it cannot see."""
        view = self._vehicle_view({"vehicle_id": state.vehicle_id}, state)
        known = alarms and (state.finished or self.safety.watches_here(state))
        return view.model_dump(mode="json", exclude=None if known else {"alarms"})

    async def stored_view(self, state: InstanceState) -> dict[str, Any]:
        """:meth:`live_view` with the alarms and the failsafe acknowledgement as the store
        has them (one read): for a push after they changed, on whichever replica."""
        view = self._vehicle_view(
            {"vehicle_id": state.vehicle_id}, state, await self._watches([state])
        )
        return view.model_dump(mode="json")

    async def vehicles(self, principal: Principal) -> list[VehicleView]:
        found = []
        for meta in await self.auth.all_vehicle_meta():
            vid = meta["vehicle_id"]
            if principal.can_see(vid):
                found.append((meta, await self.instances.current_or_latest(vid)))
        watches = await self._watches([state for _, state in found])
        return [self._vehicle_view(meta, state, watches) for meta, state in found]

    async def vehicle(self, principal: Principal, vehicle_id: str) -> VehicleView:
        meta = await self.visible_vehicle(principal, vehicle_id)
        state = await self.instances.current_or_latest(vehicle_id)
        return self._vehicle_view(meta, state, await self._watches([state]))

    async def _watches(self, states: list[InstanceState | None]) -> dict[str, StoredWatch]:
        """The stored watch state of each instance not finished (its alarms, the failsafe
        version it applies): another replica may be the one the vehicle talks to."""
        live = [s.instance_id for s in states if s is not None and not s.finished]
        return await self.safety.watches(live) if live else {}

    async def visible_vehicle(self, principal: Principal, vehicle_id: str) -> dict[str, Any]:
        """The vehicle's record, if the caller may see it: if not, it is not found, as an
        unknown one is (docs/security.md)."""
        meta = await self.auth.vehicle_meta(vehicle_id) if principal.can_see(vehicle_id) else None
        if meta is None:
            raise NotFound(f"no vehicle {vehicle_id}")
        return meta

    async def shown_name(self, meta: dict[str, Any]) -> str:
        """The vehicle's name as the fleet shows it: its instance's (the name its start
        announced), else the registered one."""
        state = await self.instances.current_or_latest(meta["vehicle_id"])
        return state.name if state is not None else str(meta.get("name") or "")

    def _vehicle_view(
        self,
        meta: dict[str, Any],
        state: InstanceState | None,
        watches: dict[str, StoredWatch] | None = None,
    ) -> VehicleView:
        """``watches``: the stored watch states (None: as this replica last saw them)."""
        if state is None:
            return VehicleView(
                vehicle_id=meta["vehicle_id"],
                name=meta.get("name", ""),
                vehicle_type=meta.get("vehicle_type", ""),
                presence="offline",
                instance_id=None,
                position=None,
                control=None,
                failsafe=self.safety.known_policy(meta["vehicle_id"]),
            )
        presence = self.instances.presence(state)
        # A link's delay is the link's now: none is shown for one that is down.
        delay_ms, rtt_ms = state.link.view() if presence in ("online", "stale") else (None, None)
        acked = self.safety.acked(state)
        if state.finished:
            alarms = []
        elif watches is None:
            alarms = self.safety.alarms(state)
        else:
            stored = watches.get(state.instance_id, StoredWatch(WatchState(), None))
            alarms = self.safety.alarms(state, stored.state)
            acked = self.safety.acked_version(state, stored.acked_version)
        return VehicleView(
            vehicle_id=state.vehicle_id,
            name=state.name,
            vehicle_type=state.vehicle_type,
            presence=presence,
            instance_id=state.instance_id,
            position=Sample.from_stored(state.position) if state.position else None,
            control=self.leases.lease_info(state.instance_id),
            control_mode=state.control_mode,
            last_seen=state.last_seen,
            failsafe=self.safety.known_policy(state.vehicle_id),
            failsafe_acked=acked,
            link_delay_ms=delay_ms,
            link_rtt_ms=rtt_ms,
            alarms=alarms,
        )

    async def connect(self, principal: Principal, body: ConnectInstance) -> InstanceView:
        if body.instance_id:
            state = await self.instances.for_viewer(principal, body.instance_id)
            if body.vehicle_id and body.vehicle_id != state.vehicle_id:
                raise NotFound(f"instance {body.instance_id} is not vehicle {body.vehicle_id}'s")
        else:
            assert body.vehicle_id is not None
            await self.visible_vehicle(principal, body.vehicle_id)
            found = await self.instances.current_or_latest(body.vehicle_id)
            if found is None:
                raise NotFound(f"vehicle {body.vehicle_id} has not started an instance yet")
            state = found
        await self.leases.current(state.instance_id)  # one instance: its lease as stored now
        return self.instance_view(state)

    async def params(
        self, principal: Principal, instance_id: str, names: list[str] | None
    ) -> GetParamResult:
        state = await self.instances.for_viewer(principal, instance_id)
        params = state.params
        if names:
            params = {k: v for k, v in params.items() if k in names}
        return GetParamResult(
            params=params,
            position=Sample.from_stored(state.position) if state.position else None,
            updated_at=state.params_updated_at,
        )
