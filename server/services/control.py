"""Control arbitration: leases per instance, control requests, grant / revoke / release.

Leases are hot state: kept in memory, one small document per instance in
the store. Whoever cares that a lease ended (the command queue cancels the
former holder's queued commands) registers in ``lease_end_listeners``;
whoever tells vehicles who holds control (their sockets) registers in
``change_listeners``.
"""

from __future__ import annotations

import secrets
from collections.abc import Awaitable, Callable, KeysView
from datetime import datetime, timedelta
from typing import Any

from fleet_protocol import ControlInfo, format_ts
from server.domain import arbitration as rules
from server.domain.access import Principal
from server.domain.arbitration import ControlRequest, Grantee, Lease
from server.errors import Forbidden, InstanceFinished
from server.services.auth import AuthService
from server.services.events import EventService
from server.services.instances import InstanceService, InstanceState
from server.services.replicas import Announce, no_announce
from server.settings import Settings
from server.storage.control import ControlRepo

Clock = Callable[[], datetime]
LeaseEndListener = Callable[[Lease, str], Awaitable[None]]
ControlChangeListener = Callable[[str, str, dict[str, Any] | None], None]


class ControlService:
    def __init__(
        self,
        settings: Settings,
        repo: ControlRepo,
        instances: InstanceService,
        auth: AuthService,
        events: EventService,
        clock: Clock,
    ) -> None:
        self.settings = settings
        self.repo = repo
        self.instances = instances
        self.auth = auth
        self.events = events
        self.clock = clock
        self._leases: dict[str, Lease] = {}
        self._requests: dict[str, list[ControlRequest]] = {}
        #: Called as ``listener(former_lease, reason)`` when a lease ends.
        self.lease_end_listeners: list[LeaseEndListener] = []
        #: Called as ``listener(instance_id, vehicle_id, control_info_or_None)``.
        self.change_listeners: list[ControlChangeListener] = []
        #: Several replicas: the store is the truth (see server/services/replicas.py).
        self.shared = settings.shared_state
        self.announce: Announce = no_announce
        instances.finish_hooks.append(self._on_finish)

    async def load(self) -> None:
        await self.repo.ensure_indexes()
        for doc in await self.repo.all_leases():
            lease = Lease.from_doc(doc)
            self._leases[lease.instance_id] = lease
        for doc in await self.repo.all_requests():
            req = _request(doc)
            self._requests.setdefault(req.instance_id, []).append(req)

    # ---- reads ----------------------------------------------------------
    def lease(self, instance_id: str) -> Lease | None:
        """The live lease on an instance, if any."""
        lease = self._leases.get(instance_id)
        return lease if lease is not None and lease.live(self.clock()) else None

    def lease_info(self, instance_id: str) -> ControlInfo | None:
        """``{holder, granted_by, expires_at}`` or None: the contract's ``control``."""
        lease = self.lease(instance_id)
        return ControlInfo(**lease.info()) if lease is not None else None

    async def requests_for(
        self, principal: Principal, instance_id: str | None
    ) -> list[dict[str, Any]]:
        """The pending requests this caller may answer (a manager of the vehicle, an admin)."""
        if instance_id is not None:
            await self.instances.find(instance_id)  # an unknown instance is a 404
        if self.shared:  # requests made on every replica
            pending = [_request(d) for d in await self.repo.requests_of(instance_id)]
        elif instance_id is not None:
            pending = self._requests.get(instance_id, [])
        else:
            pending = [r for reqs in self._requests.values() for r in reqs]
        return [r.wire() for r in pending if rules.may_grant(principal, r.vehicle_id)]

    # ---- operators and managers ------------------------------------------
    async def request(self, principal: Principal, instance_id: str) -> dict[str, Any]:
        state = await self._live_for(principal, instance_id)
        await self.refresh(state.instance_id)
        now = self.clock()
        fresh = ControlRequest(
            "r-" + secrets.token_hex(8), principal.name, state.instance_id, state.vehicle_id, now
        )
        pending, req = rules.add_request(
            self._requests.get(state.instance_id, []),
            fresh,
            limit=self.settings.max_pending_requests,
        )
        if req is fresh:
            self._requests[state.instance_id] = pending
            await self.repo.insert_request(req.wire() | {"vehicle_id": req.vehicle_id})
            await self._audit("control_request", state, principal, {"request_id": req.request_id})
        return req.wire()

    async def grant(
        self, principal: Principal, instance_id: str, username: str, duration_s: float
    ) -> Lease:
        state = await self._live_for(principal, instance_id)
        rules.check_granter(principal, state.vehicle_id)
        await self.refresh(state.instance_id)
        access = await self.auth.user_access(username)
        grantee = Grantee(username, access[0], access[1]) if access is not None else None
        rules.check_grantee(grantee, username, state.vehicle_id)
        now = self.clock()
        current = self._leases.get(state.instance_id)
        if current is not None and not current.live(now):
            await self._expire(current)  # not swept yet: its queue goes first
        lease, ended = rules.grant(
            self._leases.get(state.instance_id),
            instance_id=state.instance_id,
            vehicle_id=state.vehicle_id,
            holder=username,
            granted_by=principal.name,
            now=now,
            duration_s=duration_s,
        )
        self._leases[state.instance_id] = lease
        await self.repo.save_lease(lease.to_doc())
        self.announce(state.instance_id, "lease")
        await self._drop_request(state.instance_id, username)
        await self._audit(
            "control_grant",
            state,
            principal,
            {
                "holder": username,
                "expires_at": format_ts(lease.expires_at),
                "replaces": ended.holder if ended is not None else None,
            },
        )
        if ended is not None:
            await self._ended(ended, f"granted to {username}")
        self._changed(lease.instance_id, lease.vehicle_id, lease.info())
        return lease

    async def revoke(self, principal: Principal, instance_id: str) -> None:
        state = await self.instances.for_viewer(principal, instance_id)
        rules.check_granter(principal, state.vehicle_id)
        await self.refresh(state.instance_id)
        lease = self.lease(state.instance_id)
        await self._audit(
            "control_revoke",
            state,
            principal,
            {"holder": lease.holder if lease is not None else None},
        )
        if lease is not None:
            await self._end(lease, "revoked")

    async def release(self, principal: Principal, instance_id: str) -> None:
        state = await self.instances.for_viewer(principal, instance_id)
        await self.refresh(state.instance_id)
        lease = rules.check_release(self.lease(state.instance_id), principal, self.clock())
        await self._audit("control_release", state, principal, {"holder": lease.holder})
        await self._end(lease, "released")

    # ---- background and hooks -------------------------------------------------
    async def sweep(self, now: datetime | None = None) -> None:
        """End the leases past their expiry; forget requests nobody answered in time."""
        now = now or self.clock()
        for lease in list(self._leases.values()):
            if not lease.live(now):
                await self._expire(lease)
        too_old = now - timedelta(seconds=self.settings.control_request_ttl_s)
        for pending in list(self._requests.values()):
            for request in [r for r in pending if r.requested_at < too_old]:
                await self._drop_request(request.instance_id, request.username)

    async def _expire(self, lease: Lease) -> None:
        if await self._end(lease, "expired"):
            await self.events.record(
                "control_expired",
                vehicle_id=lease.vehicle_id,
                instance_id=lease.instance_id,
                data={"holder": lease.holder},
            )

    async def _on_finish(self, state: InstanceState, principal: Principal | None) -> None:
        await self.refresh(state.instance_id)
        self._requests.pop(state.instance_id, None)
        await self.repo.drop_requests(state.instance_id)
        lease = self._leases.get(state.instance_id)
        if lease is not None:
            await self._end(lease, "instance_finished")

    # ---- internals ------------------------------------------------------------
    async def _live_for(self, principal: Principal, instance_id: str) -> InstanceState:
        state = await self.instances.for_viewer(principal, instance_id)
        if not principal.at_least("operator"):
            raise Forbidden("control needs the operator role or above")
        if state.finished:
            raise InstanceFinished(f"instance {instance_id} is finished")
        return state

    async def _end(self, lease: Lease, reason: str) -> bool:
        """End the instance's current lease (once: False if it already ended)."""
        if self._leases.get(lease.instance_id) is not lease:
            return False
        if self.shared and not await self._claim_end(lease, reason):
            return False
        del self._leases[lease.instance_id]
        self._changed(lease.instance_id, lease.vehicle_id, None)
        if not self.shared:
            await self.repo.drop_lease(lease.instance_id)
        await self._ended(lease, reason)
        self.announce(lease.instance_id, "lease")
        return True

    # ---- several replicas -------------------------------------------------
    async def _claim_end(self, lease: Lease, reason: str) -> bool:
        """Several replicas: whether this one ends the lease (it dropped it from the store).

        An expiry drops only a lease still expired there (another replica may
        have extended it); if another replica ended or changed it, this copy
        catches up instead.
        """
        expired_by = self.clock() if reason == "expired" else None
        dropped = await self.repo.drop_lease(
            lease.instance_id, holder=lease.holder, expired_by=expired_by
        )
        if not dropped:
            await self.refresh(lease.instance_id)
        return dropped > 0

    async def refresh(
        self, instance_id: str, *, only_cached: bool = False, requests: bool = True
    ) -> None:
        """Several replicas: take the instance's lease (and, with ``requests``, its pending
        control requests) as the store has them."""
        if not self.shared or (
            only_cached
            and instance_id not in self._leases
            and self.instances.current_by_id(instance_id) is None
        ):
            return
        doc = await self.repo.lease_of(instance_id)
        if doc is None:
            self._leases.pop(instance_id, None)
        elif (stored := Lease.from_doc(doc)) != self._leases.get(instance_id):
            self._leases[instance_id] = stored
        if not requests:
            return
        pending = [_request(d) for d in await self.repo.requests_of(instance_id)]
        if pending:
            self._requests[instance_id] = pending
        else:
            self._requests.pop(instance_id, None)

    @property
    def lease_ids(self) -> KeysView[str]:
        return self._leases.keys()

    def forget(self, instance_id: str) -> None:
        """The instance finished on another replica (which ended its lease)."""
        self._leases.pop(instance_id, None)
        self._requests.pop(instance_id, None)

    async def _ended(self, lease: Lease, reason: str) -> None:
        for listener in self.lease_end_listeners:
            await listener(lease, reason)

    def _changed(self, instance_id: str, vehicle_id: str, info: dict[str, Any] | None) -> None:
        for listener in self.change_listeners:
            listener(instance_id, vehicle_id, info)

    async def _drop_request(self, instance_id: str, username: str) -> None:
        pending = self._requests.get(instance_id)
        if pending and any(r.username == username for r in pending):
            self._requests[instance_id] = [r for r in pending if r.username != username]
            await self.repo.drop_requests(instance_id, username)

    async def _audit(
        self, kind: str, state: InstanceState, principal: Principal, data: dict[str, Any]
    ) -> None:
        await self.events.record(
            kind,
            vehicle_id=state.vehicle_id,
            instance_id=state.instance_id,
            actor=principal,
            data=data,
        )


def _request(doc: dict[str, Any]) -> ControlRequest:
    return ControlRequest(
        doc["request_id"],
        doc["username"],
        doc["instance_id"],
        doc["vehicle_id"],
        doc["requested_at"],
    )
