"""Control leases: who may command an instance, who may grant that. Pure.

One holder per instance. A manager assigned to the vehicle, or an admin,
grants; the grantee is an operator (or above) with access to the vehicle.
Granting again to the holder extends the lease; granting to someone else
ends the former one. ``stop`` needs no lease; nothing but ``stop`` passes
while the vehicle reports local control.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from server.domain.access import ROLE_RANK, Principal
from server.errors import ControlNotHeld, Forbidden, Invalid, RateLimited, VehicleLocalControl


@dataclass(frozen=True)
class Lease:
    instance_id: str
    vehicle_id: str
    holder: str
    granted_by: str
    granted_at: datetime
    expires_at: datetime
    #: Raised by each write of the lease to the store (compare and set between replicas).
    rev: int = 0
    #: The lease lapses when the holder's client sends no heartbeat for this long (None:
    #: it runs to ``expires_at``); ``operator_seen_at``: its latest heartbeat (or the grant).
    operator_timeout_s: float | None = None
    operator_seen_at: datetime | None = None

    def lapse(self, now: datetime) -> str | None:
        """Why the lease no longer holds at ``now`` (``expired``, ``operator_silent``), or
        None while it does."""
        if now >= self.expires_at:
            return "expired"
        if self.operator_timeout_s is not None and self.operator_seen_at is not None:
            if (now - self.operator_seen_at).total_seconds() > self.operator_timeout_s:
                return "operator_silent"
        return None

    def live(self, now: datetime) -> bool:
        return self.lapse(now) is None

    def info(self) -> dict[str, Any]:
        return {
            "holder": self.holder,
            "granted_by": self.granted_by,
            "expires_at": self.expires_at,
            "operator_timeout_s": self.operator_timeout_s,
        }

    def to_doc(self) -> dict[str, Any]:
        return {
            "instance_id": self.instance_id,
            "vehicle_id": self.vehicle_id,
            "holder": self.holder,
            "granted_by": self.granted_by,
            "granted_at": self.granted_at,
            "expires_at": self.expires_at,
            "rev": self.rev,
            "operator_timeout_s": self.operator_timeout_s,
            "operator_seen_at": self.operator_seen_at,
        }

    @classmethod
    def from_doc(cls, doc: dict[str, Any]) -> Lease:
        return cls(
            doc["instance_id"],
            doc["vehicle_id"],
            doc["holder"],
            doc["granted_by"],
            doc["granted_at"],
            doc["expires_at"],
            int(doc.get("rev") or 0),
            doc.get("operator_timeout_s"),
            doc.get("operator_seen_at"),
        )


@dataclass(frozen=True)
class Grantee:
    """What the rules need to know of the user a lease is granted to."""

    username: str
    role: str
    vehicles: frozenset[str]
    disabled: bool = False

    def can_see(self, vehicle_id: str) -> bool:
        return self.role == "admin" or vehicle_id in self.vehicles


def may_grant(principal: Principal, vehicle_id: str) -> bool:
    """A manager assigned to the vehicle, or an admin."""
    return principal.is_admin or (principal.at_least("manager") and principal.can_see(vehicle_id))


def check_granter(principal: Principal, vehicle_id: str) -> None:
    if not may_grant(principal, vehicle_id):
        raise Forbidden(f"only a manager of vehicle {vehicle_id}, or an admin, grants its control")


def cannot_hold(grantee: Grantee | None, vehicle_id: str) -> tuple[str, str] | None:
    """Why this user may not hold control of the vehicle (a reason code and a sentence),
    or None when it may: an operator or above, enabled, with access to the vehicle."""
    if grantee is None:
        return "holder_unknown", "no such user"
    if grantee.disabled:
        return "holder_disabled", "the account is disabled"
    if ROLE_RANK.get(grantee.role, -1) < ROLE_RANK["operator"]:
        return "holder_demoted", f"a {grantee.role} cannot hold control; an operator or above can"
    if not grantee.can_see(vehicle_id):
        return "holder_lost_vehicle", f"the user has no access to vehicle {vehicle_id}"
    return None


def check_grantee(grantee: Grantee | None, username: str, vehicle_id: str) -> Grantee:
    why = cannot_hold(grantee, vehicle_id)
    if why is not None:
        raise Invalid(
            f"cannot grant control to {username}: {why[1]}",
            details=[{"field": "user", "message": why[1]}],
        )
    assert grantee is not None
    return grantee


def grant(
    current: Lease | None,
    *,
    instance_id: str,
    vehicle_id: str,
    holder: str,
    granted_by: str,
    now: datetime,
    duration_s: float,
    operator_timeout_s: float | None = None,
) -> tuple[Lease, Lease | None]:
    """The new lease, and the lease it ends (granted to someone else), if any.

    Granting again to the live holder extends the lease: it never gets shorter; its
    operator timeout becomes the one given now (the grant counts as a heartbeat).
    """
    expires_at = now + timedelta(seconds=duration_s)
    if current is not None and current.live(now) and current.holder == holder:
        lease = Lease(
            instance_id,
            vehicle_id,
            holder,
            granted_by,
            current.granted_at,
            max(expires_at, current.expires_at),
            operator_timeout_s=operator_timeout_s,
            operator_seen_at=now,
        )
        return lease, None
    ended = current if current is not None and current.live(now) else None
    lease = Lease(
        instance_id,
        vehicle_id,
        holder,
        granted_by,
        now,
        expires_at,
        operator_timeout_s=operator_timeout_s,
        operator_seen_at=now,
    )
    return lease, ended


def holds(lease: Lease | None, username: str, now: datetime) -> bool:
    return lease is not None and lease.live(now) and lease.holder == username


def check_submit(
    principal: Principal,
    *,
    command_type: str,
    lease: Lease | None,
    control_mode: str,
    now: datetime,
) -> None:
    """May this operator queue this command on this instance now?

    Access to the vehicle and the operator role are checked before (they are
    the same for every command). ``stop`` always passes.
    """
    if command_type == "stop":
        return
    if not holds(lease, principal.name, now):
        who = f" ({lease.holder} holds it)" if lease is not None and lease.live(now) else ""
        raise ControlNotHeld(f"you do not hold control of this instance{who}")
    if control_mode == "local":
        raise VehicleLocalControl("a person is at the vehicle's local controls; only stop passes")


def check_release(lease: Lease | None, principal: Principal, now: datetime) -> Lease:
    if lease is None or not lease.live(now) or lease.holder != principal.name:
        raise ControlNotHeld("you do not hold control of this instance")
    return lease


# ---- control requests ---------------------------------------------------------


@dataclass(frozen=True)
class ControlRequest:
    request_id: str
    username: str
    instance_id: str
    vehicle_id: str
    requested_at: datetime

    def wire(self) -> dict[str, Any]:
        return {
            "request_id": self.request_id,
            "username": self.username,
            "instance_id": self.instance_id,
            "requested_at": self.requested_at,
        }

    def told(self, ttl: timedelta) -> dict[str, Any]:
        """As its maker and the managers read it: with when it is dropped unanswered."""
        return self.wire() | {"expires_at": self.requested_at + ttl}

    @classmethod
    def from_doc(cls, doc: dict[str, Any]) -> ControlRequest:
        """A request as the store keeps it (its wire fields and the vehicle)."""
        return cls(
            doc["request_id"],
            doc["username"],
            doc["instance_id"],
            doc["vehicle_id"],
            doc["requested_at"],
        )


def pending_for(
    requests: Iterable[ControlRequest],
    principal: Principal,
    now: datetime,
    ttl: timedelta,
    *,
    mine: bool = False,
) -> list[ControlRequest]:
    """The requests still pending at ``now`` (each dropped ``ttl`` after it was made, the
    sweep may come a little later) that ``principal`` may answer, or, ``mine``, that it
    made; oldest first."""
    return sorted(
        (
            r
            for r in requests
            if r.requested_at + ttl > now
            and (r.username == principal.name if mine else may_grant(principal, r.vehicle_id))
        ),
        key=lambda r: r.requested_at,
    )


def add_request(
    pending: list[ControlRequest], request: ControlRequest, *, limit: int
) -> tuple[list[ControlRequest], ControlRequest]:
    """A user's request joins the instance's pending ones (once: a repeat returns the first)."""
    for existing in pending:
        if existing.username == request.username:
            return pending, existing
    if len(pending) >= limit:
        raise RateLimited(
            f"{limit} control requests are already pending on this instance", retry_after_s=30
        )
    return [*pending, request], request
