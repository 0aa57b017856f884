"""Control arbitration: leases per instance, grant / revoke / release (the requests for
control: :mod:`server.services.control_requests`).

The store holds the leases (one per instance, under its own key); this replica keeps a
copy of the leases it has seen. Every
decision reads the lease from the store first and writes it back only if it
is still as read (its ``rev``), so that of two replicas granting, revoking
or expiring one lease at once, one does it and the other reads the result.
When a lease ends, :class:`~server.domain.events.LeaseEnded` goes out (the
command queue cancels the former holder's commands), and
:class:`~server.domain.events.ControlChanged` tells who holds control now.
A user whose rights change (:class:`~server.domain.events.UserChanged`: role,
vehicles, disabled) loses the leases the new rights no longer allow.
"""

from __future__ import annotations

import dataclasses
from collections.abc import KeysView
from datetime import datetime
from typing import Any

from fleet_protocol import ControlInfo, EventKind, format_ts
from server.domain import arbitration as rules
from server.domain.access import Principal
from server.domain.arbitration import Grantee, Lease
from server.domain.clock import Clock
from server.domain.events import (
    ControlChanged,
    InstanceFinished,
    LeaseEnded,
    StateWritten,
    UserChanged,
)
from server.errors import Conflict, Forbidden, Unavailable
from server.errors import InstanceFinished as Finished
from server.services.auth import AuthService
from server.services.dead_letters import DeadLetters
from server.services.events import EventService
from server.services.instances import InstanceService, InstanceState
from server.services.messagebus import MessageBus
from server.settings import Settings
from server.storage.control import ControlRepo

#: Tries of a compare-and-set on a lease that other replicas keep changing.
_CAS_TRIES = 5


class ControlService:
    def __init__(
        self,
        settings: Settings,
        repo: ControlRepo,
        instances: InstanceService,
        auth: AuthService,
        events: EventService,
        messages: MessageBus,
        dead_letters: DeadLetters,
        clock: Clock,
    ) -> None:
        self.settings = settings
        self.repo = repo
        self.instances = instances
        self.auth = auth
        self.events = events
        self.messages = messages
        self.dead_letters = dead_letters
        self.clock = clock
        self._leases: dict[str, Lease] = {}

    async def load(self) -> None:
        """The leases, as the store has them. A lease that lapses when its holder's client
        falls silent counts that client as heard now: while this server was down, the
        client had nothing to reach, and it gets its ``operator_timeout_s`` to find the
        server back (a restart does not end every such lease: docs/safety.md)."""
        await self.repo.ensure_indexes()
        now = self.clock()
        for doc in await self.repo.all_leases():
            lease = Lease.from_doc(doc)
            if lease.operator_timeout_s is not None and now < lease.expires_at:
                if await self.repo.operator_seen(lease.instance_id, lease.holder, now):
                    lease = dataclasses.replace(lease, operator_seen_at=now)
            self._leases[lease.instance_id] = lease

    # ---- reads ----------------------------------------------------------
    def lease(self, instance_id: str) -> Lease | None:
        """The live lease on an instance as this replica last read it, if any."""
        lease = self._leases.get(instance_id)
        return lease if lease is not None and lease.live(self.clock()) else None

    def lease_info(self, instance_id: str) -> ControlInfo | None:
        """``{holder, granted_by, expires_at}`` or None: the contract's ``control``."""
        lease = self.lease(instance_id)
        return ControlInfo(**lease.info()) if lease is not None else None

    async def current(self, instance_id: str) -> Lease | None:
        """The instance's lease as the store has it now (this replica's copy caught up)."""
        doc = await self.repo.lease_of(instance_id)
        if doc is None:
            self._leases.pop(instance_id, None)
            return None
        lease = Lease.from_doc(doc)
        self._leases[instance_id] = lease
        return lease

    # ---- managers and holders ---------------------------------------------
    async def grant(
        self,
        principal: Principal,
        instance_id: str,
        username: str,
        duration_s: float,
        operator_timeout_s: float | None = None,
    ) -> Lease:
        state = await self.live_for(principal, instance_id)
        rules.check_granter(principal, state.vehicle_id)
        access = await self.auth.user_access(username)
        grantee = Grantee(username, access[0], access[1]) if access is not None else None
        rules.check_grantee(grantee, username, state.vehicle_id)
        for _ in range(_CAS_TRIES):
            current = await self.current(state.instance_id)
            now = self.clock()
            if current is not None and not current.live(now):
                await self._expire(current, now)  # not swept yet: its queue goes first
                continue
            lease, ended = rules.grant(
                current,
                instance_id=state.instance_id,
                vehicle_id=state.vehicle_id,
                holder=username,
                granted_by=principal.name,
                now=now,
                duration_s=duration_s,
                operator_timeout_s=operator_timeout_s,
            )
            lease = dataclasses.replace(lease, rev=(current.rev if current else 0) + 1)
            if await self.repo.put_lease(lease.to_doc(), current.rev if current else None):
                break
        else:
            raise Conflict("control of this instance keeps changing; try again")
        self._leases[state.instance_id] = lease
        self.messages.emit_now(StateWritten(state.instance_id, "lease"))
        if await self.repo.drop_request(state.instance_id, username):
            self.messages.emit_now(StateWritten(state.instance_id, "lease"))
        await self._audit(
            "control_grant",
            state,
            principal,
            {
                "holder": username,
                "expires_at": format_ts(lease.expires_at),
                "replaces": ended.holder if ended is not None else None,
                "operator_timeout_s": operator_timeout_s,
            },
        )
        if ended is not None:
            await self.messages.emit(LeaseEnded(ended, f"granted to {username}"))
        self._changed(lease.instance_id, lease.vehicle_id, lease.info())
        return lease

    async def revoke(self, principal: Principal, instance_id: str) -> bool:
        """End the live lease; whether there was one (none: nothing recorded)."""
        state = await self.instances.for_viewer(principal, instance_id)
        rules.check_granter(principal, state.vehicle_id)
        lease = await self.current(state.instance_id)
        live = lease if lease is not None and lease.live(self.clock()) else None
        if live is not None:
            await self._audit("control_revoke", state, principal, {"holder": live.holder})
            await self._end(live, "revoked")
        elif lease is not None:
            await self._expire(lease)
        return live is not None

    async def operator_heartbeat(self, principal: Principal, instance_ids: list[str]) -> list[str]:
        """The holder's client is alive: the leases it holds on these instances count it
        (in the store, for every replica); the instances where it holds one."""
        now = self.clock()
        held = []
        for instance_id in dict.fromkeys(instance_ids):
            lease = self._leases.get(instance_id)
            if lease is None or lease.holder != principal.name:
                lease = await self.current(instance_id)
            if lease is None or lease.holder != principal.name or not lease.live(now):
                continue
            if await self.repo.operator_seen(instance_id, principal.name, now):
                if self._leases.get(instance_id) == lease:
                    self._leases[instance_id] = dataclasses.replace(lease, operator_seen_at=now)
                held.append(instance_id)
        return held

    async def release(self, principal: Principal, instance_id: str) -> None:
        state = await self.instances.for_viewer(principal, instance_id)
        lease = rules.check_release(await self.current(state.instance_id), principal, self.clock())
        await self._audit("control_release", state, principal, {"holder": lease.holder})
        await self._end(lease, "released")

    # ---- background and handlers ----------------------------------------------
    async def sweep(self, now: datetime | None = None) -> None:
        """End the leases past their expiry."""
        now = now or self.clock()
        for lease in list(self._leases.values()):
            if not lease.live(now) and not await self._lapse(lease, now):
                return

    async def end_if_lapsed(self, instance_id: str) -> None:
        """End the instance's lease now if it has lapsed, as the sweep would a moment
        later: commands are handed out after it, so that none its holder queued goes out
        once the lease has ended."""
        lease = self._leases.get(instance_id)
        if lease is not None:
            now = self.clock()
            if not lease.live(now):
                await self._lapse(lease, now)

    async def _lapse(self, lease: Lease, now: datetime) -> bool:
        """End a lease that is no longer live (unless the store says it was renewed);
        False when the store cannot be reached (the sweep stops for this pass)."""
        try:
            if lease.lapse(now) == "operator_silent":
                # A heartbeat may have reached another replica: the store's word.
                stored = await self.current(lease.instance_id)
                if stored is None or stored.live(now):
                    return True
                lease = stored
            await self._expire(lease, now)
        except Unavailable as exc:
            self.dead_letters.failed("leases", exc)
            return False
        except Exception as exc:
            await self.dead_letters.set_aside("leases", lease.instance_id, exc, lease)
            self._leases.pop(lease.instance_id, None)  # not tried again every pass
        return True

    async def _expire(self, lease: Lease, now: datetime | None = None) -> None:
        """End a lease that lapsed: past its expiry, or its holder's client silent."""
        now = now or self.clock()
        reason = lease.lapse(now) or "expired"
        if await self._end(lease, reason):
            data: dict[str, Any] = {"holder": lease.holder, "reason": reason}
            if reason == "operator_silent" and lease.operator_seen_at is not None:
                data["operator_timeout_s"] = lease.operator_timeout_s
                data["operator_seen_at"] = format_ts(lease.operator_seen_at)
            await self.events.record(
                "control_expired",
                vehicle_id=lease.vehicle_id,
                instance_id=lease.instance_id,
                data=data,
            )

    async def on_user_changed(self, event: UserChanged) -> None:
        """End the leases the user holds and may no longer hold (demoted below operator,
        the vehicle taken away, disabled), through :meth:`_end` (their queued commands are
        cancelled, the vehicle told)."""
        rights = await self.auth.user_rights(event.username)
        grantee = Grantee(event.username, *rights) if rights is not None else None
        for doc in await self.repo.leases_held_by(event.username):
            lease = Lease.from_doc(doc)
            why = rules.cannot_hold(grantee, lease.vehicle_id)
            if why is None or not lease.live(self.clock()):
                continue  # still allowed; or past its expiry: the sweep ends it
            if await self._end(lease, why[0]):
                await self.events.record(
                    "control_revoke",
                    vehicle_id=lease.vehicle_id,
                    instance_id=lease.instance_id,
                    actor=event.actor,
                    data={"holder": lease.holder, "reason": why[0], "why": why[1]},
                )

    async def on_instance_finished(self, event: InstanceFinished) -> None:
        lease = await self.current(event.instance_id)
        if lease is not None:
            await self._end(lease, "instance_finished")

    # ---- internals ------------------------------------------------------------
    async def live_for(self, principal: Principal, instance_id: str) -> InstanceState:
        """The instance, live and seen by an operator (or above): what asking for, granting
        or holding control of it takes."""
        state = await self.instances.for_viewer(principal, instance_id)
        if not principal.at_least("operator"):
            raise Forbidden("control needs the operator role or above")
        if state.finished:
            raise Finished(f"instance {instance_id} is finished")
        return state

    async def _end(self, lease: Lease, reason: str) -> bool:
        """End this lease (the store's, as read): False when it had changed meanwhile
        (another replica ended, extended or replaced it; this copy catches up)."""
        if not await self.repo.drop_lease(lease.instance_id, lease.rev):
            await self.current(lease.instance_id)
            return False
        held = self._leases.get(lease.instance_id)
        if held is not None and (held.rev, held.holder) == (lease.rev, lease.holder):
            # this version's copy, whatever it differs in (when its client was last heard,
            # a time read back from the store): the fleet views read this replica's copy
            del self._leases[lease.instance_id]
        self.messages.emit_now(StateWritten(lease.instance_id, "lease"))
        self._changed(lease.instance_id, lease.vehicle_id, None)
        await self.messages.emit(LeaseEnded(lease, reason))
        return True

    async def refresh(self, instance_id: str) -> None:
        """Another replica changed the instance's lease: catch up, if this one keeps it
        (who holds control now reached every replica on the bus already)."""
        if instance_id in self._leases or self.instances.current_by_id(instance_id) is not None:
            await self.current(instance_id)

    @property
    def lease_ids(self) -> KeysView[str]:
        return self._leases.keys()

    def forget(self, instance_id: str) -> None:
        """The instance finished on another replica (which ended its lease)."""
        self._leases.pop(instance_id, None)

    def _changed(self, instance_id: str, vehicle_id: str, info: dict[str, Any] | None) -> None:
        self.messages.emit_now(ControlChanged(instance_id, vehicle_id, info))

    async def _audit(
        self, kind: EventKind, state: InstanceState, principal: Principal, data: dict[str, Any]
    ) -> None:
        await self.events.record(
            kind,
            vehicle_id=state.vehicle_id,
            instance_id=state.instance_id,
            actor=principal,
            data=data,
        )
