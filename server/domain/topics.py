"""Who may write and read which topic (API.md, "WebSocket", topic rules). Pure.

Writing:

- ``fleet`` and ``vehicle/<id>/{telemetry,commands,control,events}`` (and
  anything below them) are written by the server alone;
- under ``vehicle/<id>/`` only vehicle ``<id>`` writes, or a gateway that
  lists it;
- under ``user/<username>/`` only that user (a person, or a processing
  worker running with a user token);
- under ``gateway/<gateway_id>/`` only that gateway;
- nothing else.

Reading:

- ``vehicle/<id>/...`` needs read access to that vehicle (a user assigned to
  it or an admin, the vehicle itself, a gateway listing it);
- ``fleet`` is for users (the server filters presence per user);
- ``user/...`` and ``gateway/...`` are readable by every authenticated unit:
  that is how a cloud worker's results reach operators and vehicles.

The caller is anything shaped like :class:`Actor` (``server.domain.access.Principal``
is). Unit identities for the routing table come from :func:`unit_for`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal, Protocol

from fleet_protocol.topics import SERVER_ONLY_VEHICLE_TOPICS, split_topic
from server.errors import Forbidden

__all__ = [
    "Actor",
    "UnitRef",
    "can_read",
    "can_write",
    "check_read",
    "check_write",
    "read_refusal",
    "unit_for",
    "write_refusal",
]

UnitKind = Literal["vehicle", "gateway", "worker", "operator"]


class Actor(Protocol):
    """The authenticated caller, as far as topics care."""

    @property
    def kind(self) -> str: ...  # "user" | "vehicle" | "gateway"

    @property
    def name(self) -> str: ...

    def can_see(self, vehicle_id: str) -> bool: ...

    def acts_for(self, vehicle_id: str) -> bool: ...


def write_refusal(actor: Actor, topic: str) -> str | None:
    """Why ``actor`` may not publish on (or register) ``topic``; ``None`` if it may."""
    segments = split_topic(topic)
    namespace = segments[0]
    if namespace == "fleet":
        return "'fleet' is written by the server alone"
    if namespace not in ("vehicle", "user", "gateway"):
        return f"nobody writes under '{namespace}/': use user/<username>/ or vehicle/<id>/"
    if len(segments) < 3:
        return f"a topic under '{namespace}/' is '{namespace}/<id>/<name>'"
    owner, kind = segments[1], segments[2]
    if namespace == "vehicle":
        if kind in SERVER_ONLY_VEHICLE_TOPICS:
            return f"'vehicle/{owner}/{kind}' is written by the server alone"
        if not actor.acts_for(owner):
            return f"only vehicle {owner} (or its gateway) writes under 'vehicle/{owner}/'"
        return None
    if actor.kind != ("user" if namespace == "user" else "gateway") or actor.name != owner:
        return f"only {namespace} {owner} writes under '{namespace}/{owner}/'"
    return None


def read_refusal(actor: Actor, topic: str) -> str | None:
    """Why ``actor`` may not subscribe to ``topic``; ``None`` if it may."""
    segments = split_topic(topic)
    namespace = segments[0]
    if namespace == "fleet":
        return None if actor.kind == "user" else "'fleet' is for users"
    if namespace not in ("vehicle", "user", "gateway"):
        return f"there are no topics under '{namespace}/'"
    if len(segments) < 3:
        return f"a topic under '{namespace}/' is '{namespace}/<id>/<name>'"
    owner = segments[1]
    if namespace == "vehicle" and not (actor.can_see(owner) or actor.acts_for(owner)):
        return f"no read access to vehicle {owner}"
    return None


def can_write(actor: Actor, topic: str) -> bool:
    return write_refusal(actor, topic) is None


def can_read(actor: Actor, topic: str) -> bool:
    return read_refusal(actor, topic) is None


def check_write(actor: Actor, topics: str | list[str]) -> None:
    """``Forbidden`` naming the first topic ``actor`` may not write."""
    _check(write_refusal, actor, topics)


def check_read(actor: Actor, topics: str | list[str]) -> None:
    """``Forbidden`` naming the first topic ``actor`` may not read."""
    _check(read_refusal, actor, topics)


def _check(rule: Callable[[Actor, str], str | None], actor: Actor, topics: str | list[str]) -> None:
    for topic in [topics] if isinstance(topics, str) else topics:
        reason = rule(actor, topic)
        if reason is not None:
            raise Forbidden(reason, details=[{"field": "topic", "message": topic}])


@dataclass(frozen=True)
class UnitRef:
    """A unit of the routing table: its id, kind and parent gateway unit."""

    id: str
    kind: UnitKind
    parent: str | None = None


def unit_for(actor: Actor, vehicle_id: str | None = None) -> UnitRef:
    """The unit a topic op acts as: the caller, or the vehicle a gateway names.

    Unit ids carry their kind (``vehicle:usv-1``, ``gateway:gw-1``,
    ``user:alice``) so a user and a vehicle of the same name never collide.
    A vehicle may name itself; anything else naming a vehicle it does not act
    for is ``Forbidden``.
    """
    if vehicle_id is not None and not (actor.kind == "vehicle" and actor.name == vehicle_id):
        if actor.kind != "gateway" or not actor.acts_for(vehicle_id):
            raise Forbidden(f"this token does not act for vehicle {vehicle_id}")
        return UnitRef(f"vehicle:{vehicle_id}", "vehicle", parent=f"gateway:{actor.name}")
    if actor.kind == "vehicle":
        return UnitRef(f"vehicle:{actor.name}", "vehicle")
    if actor.kind == "gateway":
        return UnitRef(f"gateway:{actor.name}", "gateway")
    return UnitRef(f"user:{actor.name}", "operator")
