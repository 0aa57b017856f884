"""Whether a submit is taken, instance by instance: the checks before anything is queued.

``submit_control`` is all or nothing: every target is checked (access,
finished, capability, lease, local control, queue bound) and its args
worked out (a planned path) before one command is made. Each target's
record and lease are read from the store first.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Mapping, Sequence
from typing import Any

from fleet_protocol import CommandSpec
from server.domain import arbitration
from server.domain import commands as life
from server.domain.access import Principal
from server.domain.clock import Clock
from server.domain.planning import Zone
from server.errors import FleetError, InstanceFinished, NotFound, RateLimited
from server.services.control import ControlService
from server.services.instances import InstanceService, InstanceState
from server.services.lanes import Lane
from server.services.planning import Planning

#: Motion commands waiting on one instance; ``stop`` is never refused by this bound.
MAX_ACTIVE_PER_INSTANCE = 256

Refusal = tuple[int, str, FleetError]
Target = tuple[int, InstanceState]
#: The known fixed obstacles, read when a path is planned.
ZoneSource = Callable[[], Awaitable[Sequence[Zone]]]


class Admission:
    def __init__(
        self,
        instances: InstanceService,
        control: ControlService,
        planning: Planning,
        zones: ZoneSource,
        lanes: Mapping[str, Lane],
        clock: Clock,
    ) -> None:
        self.instances = instances
        self.control = control
        self.planning = planning
        self.zones = zones
        self.lanes = lanes
        self.clock = clock

    async def targets(
        self, principal: Principal, ids: list[str]
    ) -> tuple[list[Target], list[Refusal]]:
        """The instances named (``["*"]``: every live one the caller sees), as the store has
        them, their leases read again; an unknown one is a refusal."""
        if ids == ["*"]:
            live = [
                s
                for s in await self.instances.everyone()
                if not s.finished and principal.can_see(s.vehicle_id)
            ]
            targets = list(enumerate(sorted(live, key=lambda s: s.vehicle_id)))
            refusals: list[Refusal] = []
        else:
            targets, refusals = [], []
            for index, instance_id in enumerate(ids):
                try:
                    targets.append((index, await self.instances.fresh(instance_id)))
                except FleetError as exc:
                    refusals.append((index, instance_id, exc))
        for _, state in targets:  # a lease granted or ended on another replica counts here
            await self.control.current(state.instance_id)
        return targets, refusals

    def check_all(
        self, principal: Principal, targets: list[Target], spec: CommandSpec
    ) -> list[Refusal]:
        refusals = []
        for index, state in targets:
            try:
                self.admit(principal, state, spec)
            except FleetError as exc:
                refusals.append((index, state.instance_id, exc))
        return refusals

    def admit(self, principal: Principal, state: InstanceState, spec: CommandSpec) -> None:
        """Check one instance takes this command from this caller now."""
        if not principal.can_see(state.vehicle_id):  # as an unknown one (docs/security.md)
            raise NotFound(f"no instance {state.instance_id}")
        if state.finished:
            raise InstanceFinished(f"instance {state.instance_id} is finished")
        life.check_capability(spec.type, state.capabilities)
        arbitration.check_submit(
            principal,
            command_type=spec.type,
            lease=self.control.lease(state.instance_id),
            control_mode=state.control_mode,
            now=self.clock(),
        )
        lane = self.lanes.get(state.instance_id)
        if spec.type != "stop" and lane is not None and len(lane.active) >= MAX_ACTIVE_PER_INSTANCE:
            raise RateLimited(f"{MAX_ACTIVE_PER_INSTANCE} commands already wait on this instance")

    async def args_for(
        self, targets: list[Target], spec: CommandSpec
    ) -> tuple[dict[str, dict[str, Any]], list[Refusal]]:
        """Each target's args: planned if asked (off the event loop, all of them within
        one deadline), the obstacles read once for all of them; a target the planner
        refuses is a refusal."""
        plan = spec.type == "follow_path" and bool(spec.args.get("plan"))
        zones = await self.zones() if plan else ()
        others_all = await self.instances.everyone() if plan else []
        deadline = self.planning.deadline()
        by_instance: dict[str, dict[str, Any]] = {}
        refusals: list[Refusal] = []
        for index, state in targets:
            args = dict(spec.args)
            if plan:
                others = [s for s in others_all if s.instance_id != state.instance_id]
                try:
                    args = await self.planning.plan(state, args, others, zones, deadline)
                except FleetError as exc:
                    refusals.append((index, state.instance_id, exc))
                    continue
            by_instance[state.instance_id] = args
        return by_instance, refusals
