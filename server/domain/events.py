"""What one part of the server tells the others. Pure data.

A service that must let others know something emits one of these through
the message bus (:mod:`server.services.messagebus`); the handlers are
registered once, in the composition root (``server/container.py``), so
that services depend on each other one way only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from server.domain.access import Principal
from server.domain.arbitration import Lease
from server.domain.presence import Presence

#: The parts of an instance's state another replica may keep a copy of.
StatePart = Literal["instance", "lease", "commands", "watch"]


@dataclass(frozen=True, slots=True)
class StateWritten:
    """A part of an instance's state was just written to the store (other replicas
    that keep a copy read it again)."""

    instance_id: str
    part: StatePart


@dataclass(frozen=True, slots=True)
class InstanceFinished:
    instance_id: str
    vehicle_id: str
    actor: Principal | None


@dataclass(frozen=True, slots=True)
class PresenceChanged:
    instance_id: str
    vehicle_id: str
    presence: Presence


@dataclass(frozen=True, slots=True)
class ControlChanged:
    """Who holds control of an instance now (``control`` None: nobody)."""

    instance_id: str
    vehicle_id: str
    control: dict[str, Any] | None


@dataclass(frozen=True, slots=True)
class LeaseEnded:
    lease: Lease
    reason: str


@dataclass(frozen=True, slots=True)
class CommandsReady:
    """An instance has commands to hand out (new, or due for redelivery)."""

    instance_id: str


@dataclass(frozen=True, slots=True)
class CommandMoved:
    """A command moved on without ending (handed out, accepted, executing): its last
    history entry says how. The start and the end of a command are events of the log
    (``EventRecorded``, kind ``command``)."""

    vehicle_id: str
    command_id: str
    type: str
    status: str
    detail: str | None
    progress: float | None
    issued_by: str = ""


@dataclass(frozen=True, slots=True)
class SamplesStored:
    """Samples accepted for a vehicle (in their stored form: dicts, read only), in the
    order received, and whether each came late;
    ``current``: the one that became the vehicle's latest position and came in time
    (None: none did: all came late, or are dated too far ahead). What judges the vehicle
    as it is now (its zones, its battery) reads ``current`` alone."""

    vehicle_id: str
    samples: list[Any]
    replayed: list[bool]
    current: Any = None
    #: A sample dated after this (a clock glitch: 2099) is stored as sent but never the
    #: vehicle's position (None: no bound was taken, as for a batch stored whole).
    ahead_after: Any = None


@dataclass(frozen=True, slots=True)
class EventRecorded:
    """An entry of the event log (its stored document)."""

    doc: dict[str, Any]


@dataclass(frozen=True, slots=True)
class TokensRevoked:
    """Tokens that stopped being valid: by id (their sockets close) and digest (caches).
    With ``revoked`` False they still are, but what they may do changed (their user's
    role or vehicles): read again, and their sockets close for the client to reconnect."""

    token_ids: frozenset[str]
    digests: frozenset[str]
    #: False when the news came from another replica (it is not sent on again).
    local: bool = True
    revoked: bool = True


@dataclass(frozen=True, slots=True)
class UserChanged:
    """A user's role, vehicles or ``disabled`` changed (an admin's PATCH): whatever the
    user held under the former rights and may no longer hold ends (its leases)."""

    username: str
    actor: Principal | None = None


@dataclass(frozen=True, slots=True)
class FailsafeChanged:
    """A vehicle's failsafe policy changed (its wire form): its live instance is told."""

    vehicle_id: str
    policy: dict[str, Any]


@dataclass(frozen=True, slots=True)
class ZonesChanged:
    """A zone was drawn, changed or deleted: the set's ``version`` now (the vehicles'
    watch judges their latest positions again)."""

    version: int


@dataclass(frozen=True, slots=True)
class LinkChanged:
    """A vehicle's measured link delay moved enough to tell its view again."""

    instance_id: str
    vehicle_id: str
