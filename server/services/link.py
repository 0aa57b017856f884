"""The vehicle's link to the server: the use cases behind ``/upper/*`` and ``/ws/vehicle``.

One place composes instances, telemetry and control for what a vehicle does,
so the HTTP routes and the WebSocket ops call the same methods.
"""

from __future__ import annotations

import difflib
import time
from collections.abc import Awaitable, Callable, Sequence
from datetime import datetime
from typing import Any, Protocol

from fleet_protocol import (
    ControlInfo,
    FailsafePolicy,
    FinishInstanceResult,
    HeartbeatResult,
    Sample,
    StartInstance,
    StartInstanceResult,
    UpdateFbMessage,
    UpdateParam,
    WhoAmIResult,
    format_ts,
)
from server.domain.access import Principal
from server.domain.commands import Command, position_is_current
from server.domain.events import LinkChanged, SamplesStored
from server.domain.latency import one_way_delay_s
from server.errors import Invalid
from server.metrics import Hops
from server.services.instances import InstanceService, InstanceState
from server.services.messagebus import MessageBus
from server.settings import Settings


class IngestResult(Protocol):
    accepted: int
    duplicates: int
    acked_through_seq: int
    durable_through_seq: int
    #: Samples in their stored form (dicts).
    latest: dict[str, Any] | None
    stored: list[dict[str, Any]]
    replayed: list[bool]
    current: dict[str, Any] | None
    ahead_after: datetime | None


class Telemetry(Protocol):
    async def ingest(
        self,
        vehicle_id: str,
        instance_id: str,
        samples: Sequence[Sample | dict[str, Any]],
        clock_offset_s: float = 0.0,
        arrived: datetime | None = None,
    ) -> IngestResult: ...

    def takes_now(self, vehicle_id: str, count: int) -> bool: ...

    def ingest_now(
        self,
        vehicle_id: str,
        samples: Sequence[Sample | dict[str, Any]],
        clock_offset_s: float = 0.0,
        arrived: datetime | None = None,
    ) -> IngestResult: ...

    async def last_seq(self, vehicle_id: str) -> int: ...


class Leases(Protocol):
    def lease_info(self, instance_id: str) -> ControlInfo | None: ...

    async def current(self, instance_id: str) -> Any:
        """The lease as the store has it now (the copy behind ``lease_info`` caught up)."""


class Failsafes(Protocol):
    async def for_start(self, state: InstanceState) -> FailsafePolicy: ...

    async def pending(self, state: InstanceState) -> FailsafePolicy | None: ...

    async def acknowledge(self, state: InstanceState, version: int | None) -> None: ...


class Feedback(Protocol):
    async def acknowledge(
        self,
        principal: Principal,
        instance_id: str,
        control_mode: str | None,
        acks: list[Any],
        since: datetime | None = None,
    ) -> list[str]: ...

    async def reconcile(self, state: InstanceState, active: list[str]) -> list[str]: ...

    def ready(self, instance_id: str) -> None: ...

    async def get_control(
        self,
        principal: Principal,
        instance_id: str,
        wait_s: float,
        news: Callable[[InstanceState], Awaitable[object]] | None = None,
    ) -> tuple[list[Command], list[str]]: ...


class VehicleLink:
    def __init__(
        self,
        settings: Settings,
        instances: InstanceService,
        telemetry: Telemetry,
        leases: Leases,
        feedback: Feedback,
        failsafes: Failsafes,
        messages: MessageBus,
        hops: Hops,
    ) -> None:
        self.settings = settings
        self.instances = instances
        self.telemetry = telemetry
        self.leases = leases
        self.commands = feedback
        self.failsafes = failsafes
        self.messages = messages
        self.hops = hops

    async def start(self, principal: Principal, body: StartInstance) -> StartInstanceResult:
        state, resumed = await self.instances.start(principal, body)
        abort: list[str] = []
        if body.active_commands is not None:
            abort = await self.commands.reconcile(state, body.active_commands)
        s = self.settings
        failsafe = await self.failsafes.for_start(state)
        state.failsafe_told = failsafe.version  # the answer carries it
        return StartInstanceResult(
            instance_id=state.instance_id,
            resumed=resumed,
            last_seq=max(0, await self.telemetry.last_seq(state.vehicle_id)),
            heartbeat_interval_s=s.heartbeat_interval_s,
            stale_after_s=s.stale_after_s,
            offline_after_s=s.offline_after_s,
            ack_timeout_s=s.ack_timeout_s,
            server_time=self.instances.clock(),
            failsafe=failsafe,
            control=self.leases.lease_info(state.instance_id),
            abort=abort,
        )

    async def live(
        self, principal: Principal, instance_id: str, now: datetime | None = None
    ) -> InstanceState:
        """The caller's live instance; the call counts as contact (at ``now``, read from
        the clock when not given)."""
        state = await self.instances.for_vehicle_caller(principal, instance_id)
        self.instances.touch(state, now)
        return state

    async def finish(self, principal: Principal, instance_id: str) -> FinishInstanceResult:
        state = await self.instances.for_vehicle_caller(principal, instance_id)
        await self.instances.finish(principal, state)
        return FinishInstanceResult(instance_id=instance_id)

    async def feedback(self, principal: Principal, body: UpdateFbMessage) -> list[str]:
        """The vehicle's acks, control mode and failsafe version; the ``abort`` list."""
        abort = await self.commands.acknowledge(
            principal, body.instance_id, body.control_mode, body.acks, body.control_mode_since
        )
        if body.failsafe_version is not None:
            state = await self.instances.for_vehicle_caller(principal, body.instance_id)
            await self.failsafes.acknowledge(state, body.failsafe_version)
        return abort

    async def get_control(
        self, principal: Principal, instance_id: str, wait_s: float
    ) -> tuple[list[Command], list[str]]:
        """The commands due and the aborts (:meth:`CommandDelivery.get_control`); a long
        poll also ends as soon as the vehicle has a failsafe policy to apply that no
        answer carried yet (a client that never acknowledges one is not answered at
        once poll after poll)."""
        return await self.commands.get_control(
            principal, instance_id, wait_s, news=self._failsafe_news
        )

    async def _failsafe_news(self, state: InstanceState) -> bool:
        policy = await self.failsafes.pending(state)
        return policy is not None and policy.version != state.failsafe_told

    async def pending_failsafe(
        self, principal: Principal, instance_id: str
    ) -> FailsafePolicy | None:
        """The vehicle's policy, while it has not acknowledged the current version."""
        state = await self.instances.for_vehicle_caller(principal, instance_id)
        policy = await self.failsafes.pending(state)
        if policy is not None:
            state.failsafe_told = policy.version
        return policy

    async def heartbeat(self, principal: Principal, instance_id: str) -> HeartbeatResult:
        await self.live(principal, instance_id)
        return HeartbeatResult(server_time=self.instances.clock())

    @staticmethod
    def whoami(principal: Principal) -> WhoAmIResult:
        """Whom a vehicle's or a gateway's token acts for (a gateway refuses other units)."""
        if principal.kind == "vehicle":
            return WhoAmIResult(
                kind="vehicle", vehicle_id=principal.name, vehicles=[principal.name]
            )
        return WhoAmIResult(
            kind="gateway", gateway_id=principal.name, vehicles=sorted(principal.vehicles)
        )

    async def update_param(
        self, principal: Principal, body: UpdateParam, transport: str = "http"
    ) -> dict[str, Any]:
        """Merge the params, store the samples; the fields of ``UpdateParamResult``
        (a dict: the socket's ack is built from it with no model in between).
        ``transport`` (``ws``, ``http``) labels the call's delay in ``/metrics``."""
        done = self.update_param_now(principal, body, transport)
        if done is not None:
            return done
        arrived = self.instances.clock()  # the call's one reading of the clock
        state = await self.live(principal, body.instance_id, arrived)
        self._merge(state, body, arrived, transport)
        result = await self.telemetry.ingest(
            state.vehicle_id, state.instance_id, body.samples, state.clock_offset_s, arrived
        )
        return self._after_ingest(state, result, arrived)

    def update_param_now(
        self, principal: Principal, body: UpdateParam, transport: str
    ) -> dict[str, Any] | None:
        """:meth:`update_param` within this call when nothing has to wait (this replica
        keeps the instance, the vehicle's open bucket takes the samples); None when
        something would, and then nothing was done."""
        if body.model_extra and not _SAID & body.model_fields_set:
            raise _only_unknown(body.model_extra)
        state = self.instances.kept_for_vehicle_caller(principal, body.instance_id)
        if state is None or not self.telemetry.takes_now(state.vehicle_id, len(body.samples)):
            return None
        arrived = self.instances.clock()
        self.instances.touch(state, arrived)
        self._merge(state, body, arrived, transport)
        result = self.telemetry.ingest_now(
            state.vehicle_id, body.samples, state.clock_offset_s, arrived
        )
        return self._after_ingest(state, result, arrived)

    def _merge(
        self, state: InstanceState, body: UpdateParam, arrived: datetime, transport: str
    ) -> None:
        if body.clock_offset_s is not None:
            state.clock_offset_s = body.clock_offset_s
        if body.sent_at is not None:
            self._timed(state, body, arrived, transport)
        self.instances.merge_params(state, body.params, arrived)

    def _after_ingest(
        self, state: InstanceState, result: IngestResult, arrived: datetime
    ) -> dict[str, Any]:
        if result.latest is not None:
            self.instances.set_position(state, result.latest)
            if state.drift_held and position_is_current(
                state.position, state.vehicle_clock(arrived), self.settings.offline_after_s
            ):
                state.drift_held = False
                self.commands.ready(state.instance_id)  # its drift can be judged now
        if result.stored:
            self.messages.emit_now(
                SamplesStored(
                    state.vehicle_id,
                    result.stored,
                    result.replayed,
                    result.current,
                    result.ahead_after,
                )
            )
        return {
            "accepted": result.accepted,
            "duplicates": result.duplicates,
            "acked_through_seq": max(0, result.acked_through_seq),
            "durable_through_seq": max(0, result.durable_through_seq),
            "server_time": format_ts(arrived),
        }

    def _timed(
        self, state: InstanceState, body: UpdateParam, arrived: datetime, transport: str
    ) -> None:
        """The call's vehicle → server delay: into ``/metrics`` and the vehicle's view."""
        assert body.sent_at is not None
        delay = one_way_delay_s(body.sent_at, arrived, body.clock_offset_s)
        self.hops.vehicle_to_server(transport, delay)
        if state.link.observe(delay, body.rtt_s, time.monotonic()):
            self.messages.emit_now(LinkChanged(state.instance_id, state.vehicle_id))


#: What an ``update_param`` carries: one of them sent (even empty), its unknown fields are
#: a newer client's, ignored.
_SAID = frozenset({"params", "samples"})


def _only_unknown(extra: dict[str, Any]) -> Invalid:
    """The refusal of an ``update_param`` whose only fields are ones it does not know: it
    would change nothing, and the vehicle would take "0 accepted" for its samples."""
    name = next(iter(extra))
    guess = difflib.get_close_matches(name, ("params", "samples"), n=1)
    said = f"{name}: not a field of update_param" + (f": did you mean {guess[0]}?" if guess else "")
    return Invalid(
        f"{said} (it takes params and samples; this call has neither)",
        details=[{"field": name, "message": said}],
    )
