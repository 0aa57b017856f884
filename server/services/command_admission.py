"""Whether a submit is taken, instance by instance: the checks before anything is queued.

``submit_control`` is all or nothing: every target is checked (access,
finished, capability, lease, local control, queue bound) and its args
worked out (a planned path) before one command is made. Each target's
record and lease are read from the store first.

Where a command sends a vehicle is checked against the zones
(:mod:`server.domain.zones`): a target in a no-go zone of the vehicle, or a way
there through one, or out of its operating area, is refused naming the zone. A
planned path goes round the fixed obstacles, the vehicle's no-go zones and the
outside of its operating area, and keeps ``FLEET_SEPARATION_M`` from the paths
planned before it in the same submit. A ``follow_path`` carries the hash of its
route (``path_hash``), which the vehicle acknowledges before it starts.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Mapping, Sequence
from datetime import datetime
from typing import Any

from fleet_protocol import CommandSpec, path_hash, route_of
from server.domain import arbitration
from server.domain import command_warnings as warn
from server.domain import commands as life
from server.domain.access import Principal
from server.domain.clock import Clock
from server.domain.plan_frame import Zone, corridor, crossed
from server.domain.zones import ZoneSet, command_targets, command_violation, keep_out
from server.errors import FleetError, InstanceFinished, NotFound, RateLimited, ZoneViolation
from server.services.control import ControlService
from server.services.instances import InstanceService, InstanceState
from server.services.lanes import Lane
from server.services.planning import Planning

#: Motion commands waiting on one instance; ``stop`` is never refused by this bound.
MAX_ACTIVE_PER_INSTANCE = 256

Refusal = tuple[int, str, FleetError]
Target = tuple[int, InstanceState]
#: The known fixed obstacles, read when a path is planned.
ObstacleSource = Callable[[], Awaitable[Sequence[Zone]]]
#: The operating areas and no-go zones as the store has them now.
ZoneSetSource = Callable[[], Awaitable[ZoneSet]]


def position_of(state: InstanceState) -> tuple[float, float] | None:
    here = state.position
    return (float(here["lat"]), float(here["lon"])) if here is not None else None


def zone_refusal(
    zones: ZoneSet, state: InstanceState, kind: str, args: dict[str, Any]
) -> ZoneViolation | None:
    """Why the zones refuse this command to the instance where it is now, if they do."""
    found = command_violation(zones, state.vehicle_id, kind, args, position_of(state))
    if found is None:
        return None
    return ZoneViolation(found.message, zone_id=found.zone_id, zone=found.name, kind=found.kind)


class Admission:
    def __init__(
        self,
        instances: InstanceService,
        control: ControlService,
        planning: Planning,
        obstacles: ObstacleSource,
        zones: ZoneSetSource,
        separation_m: float,
        lanes: Mapping[str, Lane],
        clock: Clock,
    ) -> None:
        self.instances = instances
        self.control = control
        self.planning = planning
        self.obstacles = obstacles
        self.zones = zones
        self.separation_m = separation_m
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

    async def warnings(
        self,
        targets: list[Target],
        spec: CommandSpec,
        args: dict[str, dict[str, Any]],
        expires: datetime,
    ) -> list[str]:
        """What a submit queued as asked does that its sender may not have meant: several
        vehicles sent to meet, a straight way into a known obstacle, a vehicle not online
        that the command waits for."""
        meet = warn.shared_target(spec.type, spec.args, len(targets), self.separation_m)
        out = [meet] if meet else []
        out += await self._obstacles_met(targets, spec, args)
        for _, state in targets:
            presence = self.instances.presence(state)
            if presence not in ("online", "finished"):
                out.append(warn.out_of_reach(state.name, presence, state.last_seen, expires))
        return out

    async def _obstacles_met(
        self, targets: list[Target], spec: CommandSpec, args: dict[str, dict[str, Any]]
    ) -> list[str]:
        """For a ``go_to`` or a path not planned: each vehicle whose straight way runs into
        a known fixed obstacle, said (the zones refuse such a way; an obstacle is the
        planner's to go round, and a vehicle's own sensors may see it too)."""
        if spec.type not in ("go_to", "follow_path") or spec.args.get("plan"):
            return []
        fixed = await self.obstacles()
        if not fixed:
            return []
        out = []
        for _, state in targets:
            start = position_of(state)
            way = command_targets(spec.type, args[state.instance_id])
            hit = crossed([start, *way] if start is not None else way, fixed)
            if hit:
                out.append(
                    f"{state.name}'s straight way runs into {', '.join(hit)}: a known fixed "
                    "obstacle (a path planned with plan: true goes round it)"
                )
        return out

    async def args_for(
        self, targets: list[Target], spec: CommandSpec
    ) -> tuple[dict[str, dict[str, Any]], list[Refusal], int]:
        """Each target's args: planned if asked (off the event loop, all of them within
        one deadline, each keeping the separation from those planned before it), then
        checked against the zones; a target refused is a refusal. With them, the version
        of the zones they were checked against."""
        plan = spec.type == "follow_path" and bool(spec.args.get("plan"))
        zones = await self.zones()
        fixed = await self.obstacles() if plan else ()
        others_all = await self.instances.everyone() if plan else []
        deadline = self.planning.deadline()
        by_instance: dict[str, dict[str, Any]] = {}
        refusals: list[Refusal] = []
        planned: list[Zone] = []  # the corridors of the paths planned so far
        for index, state in targets:
            args = dict(spec.args)
            if plan:
                others = [s for s in others_all if s.instance_id != state.instance_id]
                avoid = [*fixed, *keep_out(zones, state.vehicle_id), *planned]
                try:
                    args = await self.planning.plan(state, args, others, avoid, deadline)
                except FleetError as exc:
                    refusals.append((index, state.instance_id, exc))
                    continue
            violation = zone_refusal(zones, state, spec.type, args)
            if violation is not None:
                refusals.append((index, state.instance_id, violation))
                continue
            if spec.type == "follow_path":
                args["path_hash"] = path_hash(route_of(args))
                route = [(float(p["lat"]), float(p["lon"])) for p in route_of(args)]
                start = position_of(state)
                if plan and self.separation_m > 0 and len(targets) > 1:
                    name = (
                        f"the {self.separation_m:g} m about the path planned for "
                        f"{state.vehicle_id} (vehicles sent together keep that far apart: "
                        "give each its own waypoints, or send them one at a time)"
                    )
                    way = [start, *route] if start is not None else route
                    planned.append(corridor(way, self.separation_m, name))
            by_instance[state.instance_id] = args
        return by_instance, refusals, zones.version
