"""Requests for control: an operator asks for a vehicle, a field manager (or an admin)
sees what is pending and answers it, by a grant (:class:`~server.services.control.
ControlService`, which drops the grantee's request) or a decline. An unanswered request is
dropped after ``FLEET_CONTROL_REQUEST_TTL_S``, and those of a user whose rights no longer
allow the vehicle, or of a finished instance, at once. The store keeps them, one per user
and instance: every replica answers from it.
"""

from __future__ import annotations

import secrets
from datetime import datetime, timedelta
from typing import Any

from fleet_protocol import format_ts
from server.domain import arbitration as rules
from server.domain.access import Principal
from server.domain.arbitration import ControlRequest, Grantee
from server.domain.clock import Clock
from server.domain.events import InstanceFinished, StateWritten, UserChanged
from server.errors import Conflict, NotFound, Unavailable
from server.services.auth import AuthService
from server.services.control import ControlService
from server.services.dead_letters import DeadLetters
from server.services.events import EventService
from server.services.instances import InstanceService
from server.services.messagebus import MessageBus
from server.settings import Settings
from server.storage.control import ControlRepo


class ControlRequests:
    def __init__(
        self,
        settings: Settings,
        repo: ControlRepo,
        control: ControlService,
        instances: InstanceService,
        auth: AuthService,
        events: EventService,
        messages: MessageBus,
        dead_letters: DeadLetters,
        clock: Clock,
    ) -> None:
        self.settings = settings
        self.repo = repo
        self.control = control
        self.instances = instances
        self.auth = auth
        self.events = events
        self.messages = messages
        self.dead_letters = dead_letters
        self.clock = clock

    @property
    def ttl(self) -> timedelta:
        """How long a request waits for an answer before it is dropped."""
        return timedelta(seconds=self.settings.control_request_ttl_s)

    async def pending(
        self, principal: Principal, instance_id: str | None, *, mine: bool = False
    ) -> list[dict[str, Any]]:
        """The pending requests this caller may answer (a manager of the vehicle, an admin);
        ``mine``: the ones the caller made and nobody has answered yet. Oldest first, each
        with the time it is dropped unanswered (``expires_at``)."""
        if instance_id is not None:
            await self.instances.for_viewer(principal, instance_id)  # unknown or unseen: 404
        if mine:
            docs = await self.repo.requests_by(principal.name)
            docs = [d for d in docs if instance_id in (None, d["instance_id"])]
        elif instance_id is not None:
            docs = await self.repo.requests_of(instance_id)
        else:
            docs = await self.repo.all_requests()
        asked = (ControlRequest.from_doc(d) for d in docs)
        pending = rules.pending_for(asked, principal, self.clock(), self.ttl, mine=mine)
        return [r.told(self.ttl) for r in pending]

    async def request(self, principal: Principal, instance_id: str) -> dict[str, Any]:
        """Ask for control of the instance (asked again, the first request stands)."""
        state = await self.control.live_for(principal, instance_id)
        lease = await self.control.current(state.instance_id)
        if lease is not None and lease.holder == principal.name and lease.live(self.clock()):
            raise Conflict(
                f"you hold control of {state.name} until {format_ts(lease.expires_at)}: "
                "nothing to ask (a manager extends a lease by granting it again)",
                code="control_held",
            )
        fresh = ControlRequest(
            "r-" + secrets.token_hex(8),
            principal.name,
            state.instance_id,
            state.vehicle_id,
            self.clock(),
        )
        stored_requests = await self.repo.requests_of(state.instance_id)
        pending = [ControlRequest.from_doc(d) for d in stored_requests]
        _, req = rules.add_request(pending, fresh, limit=self.settings.max_pending_requests)
        if req is not fresh:
            return req.told(self.ttl)  # asked already: the first request stands
        if not await self.repo.insert_request(req.wire() | {"vehicle_id": req.vehicle_id}):
            stored = await self.repo.request_of(state.instance_id, principal.name)
            req = ControlRequest.from_doc(stored) if stored is not None else req
            return req.told(self.ttl)
        await self.events.record(
            "control_request",
            vehicle_id=state.vehicle_id,
            instance_id=state.instance_id,
            actor=principal,
            data={"request_id": req.request_id},
        )
        return req.told(self.ttl)

    async def deny(
        self, principal: Principal, instance_id: str, username: str, reason: str | None
    ) -> None:
        """Decline the user's pending request (404 when there is none)."""
        state = await self.instances.for_viewer(principal, instance_id)
        rules.check_granter(principal, state.vehicle_id)
        if not await self.repo.drop_request(state.instance_id, username):
            raise NotFound(f"no pending request for control from {username}")
        self.messages.emit_now(StateWritten(state.instance_id, "lease"))
        await self.events.record(
            "control_deny",
            vehicle_id=state.vehicle_id,
            instance_id=state.instance_id,
            actor=principal,
            data={"user": username, "reason": reason},
        )

    # ---- background and handlers ----------------------------------------------
    async def sweep(self, now: datetime | None = None) -> None:
        """Forget the requests nobody answered in time."""
        too_old = (now or self.clock()) - self.ttl
        try:
            for doc in await self.repo.drop_requests_before(too_old):
                self.messages.emit_now(StateWritten(doc["instance_id"], "lease"))
        except Unavailable as exc:
            self.dead_letters.failed("leases", exc)

    async def on_user_changed(self, event: UserChanged) -> None:
        """Drop the user's pending requests its new rights no longer allow."""
        rights = await self.auth.user_rights(event.username)
        grantee = Grantee(event.username, *rights) if rights is not None else None
        for doc in await self.repo.requests_by(event.username):
            if rules.cannot_hold(grantee, doc["vehicle_id"]) is not None:
                if await self.repo.drop_request(doc["instance_id"], event.username):
                    self.messages.emit_now(StateWritten(doc["instance_id"], "lease"))

    async def on_instance_finished(self, event: InstanceFinished) -> None:
        await self.repo.drop_requests(event.instance_id)
