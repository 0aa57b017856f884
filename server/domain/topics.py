"""Who may write and read which topic (API.md, "WebSocket", topic rules). Pure.

Writing:

- ``fleet``, ``zones`` and ``vehicle/<id>/{telemetry,commands,control,events}``
  (and anything below them) are written by the server alone;
- under ``vehicle/<id>/`` only vehicle ``<id>`` writes, or a gateway that
  lists it;
- under ``user/<username>/`` only that user (a person, or a processing
  worker running with a user token);
- under ``gateway/<gateway_id>/`` only that gateway;
- nothing else.

Reading: the one rule the gateway applies too,
:func:`fleet_protocol.topics.read_refusal` (every namespace has an owner; ``fleet`` and
``zones`` are for users).

The caller is anything shaped like :class:`Actor` (``server.domain.access.Principal``
is). Unit identities for the routing table come from :func:`unit_for`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Literal, Protocol

from fleet_protocol.topics import SERVER_ONLY_VEHICLE_TOPICS, Reader, shape_problem, split_topic
from fleet_protocol.topics import read_refusal as shared_read_refusal
from server.errors import Forbidden, Invalid

__all__ = [
    "Actor",
    "UnitRef",
    "can_read",
    "can_write",
    "check_read",
    "check_write",
    "gateways_named",
    "read_refusal",
    "unit_for",
    "write_refusal",
]

UnitKind = Literal["vehicle", "gateway", "worker", "operator"]


class Actor(Reader, Protocol):
    """The authenticated caller, as far as topics care (who reads is
    :class:`fleet_protocol.topics.Reader`; the server can always tell)."""

    def reads_vehicle(self, vehicle_id: str) -> bool: ...

    def can_see(self, vehicle_id: str) -> bool: ...

    def acts_for(self, vehicle_id: str) -> bool: ...


def vehicle_written(topic: str) -> bool:
    """A topic a vehicle (or a unit behind its gateway) writes: ``vehicle/<id>/<name>...``,
    not one the server writes alone (as :func:`write_refusal` judges it)."""
    segments = topic.split("/")
    return (
        len(segments) >= 3
        and segments[0] == "vehicle"
        and segments[2] not in SERVER_ONLY_VEHICLE_TOPICS
    )


def write_refusal(actor: Actor, topic: str, as_vehicle: str | None = None) -> str | None:
    """Why ``actor`` may not publish on (or register) ``topic``; ``None`` if it may.
    ``as_vehicle``: the vehicle a gateway's op acts for (its ``vehicle_id``), which writes
    under its own ``vehicle/<id>/`` alone, as that vehicle's own token does."""
    if (problem := shape_problem(topic)) is not None:
        return problem
    segments = split_topic(topic)
    namespace = segments[0]
    if namespace in ("fleet", "zones"):
        return f"'{namespace}' is written by the server alone"
    owner, kind = segments[1], segments[2]
    if namespace == "vehicle":
        if kind in SERVER_ONLY_VEHICLE_TOPICS:
            return f"'vehicle/{owner}/{kind}' is written by the server alone"
        if not actor.acts_for(owner):
            return f"only vehicle {owner} (or its gateway) writes under 'vehicle/{owner}/'"
        if as_vehicle is not None and owner != as_vehicle:
            return f"acting for vehicle {as_vehicle}, it writes under 'vehicle/{as_vehicle}/' alone"
        return None
    if as_vehicle is not None:
        return f"acting for vehicle {as_vehicle}, it writes under 'vehicle/{as_vehicle}/' alone"
    if actor.kind != ("user" if namespace == "user" else "gateway") or actor.name != owner:
        return f"only {namespace} {owner} writes under '{namespace}/{owner}/'"
    return None


#: The vehicles each gateway named in the topics lists (resolved by the caller).
Gateways = Mapping[str, frozenset[str]]


def read_refusal(actor: Actor, topic: str, gateways: Gateways | None = None) -> str | None:
    """Why ``actor`` may not subscribe to ``topic``; ``None`` if it may (the rule:
    :func:`fleet_protocol.topics.read_refusal`). ``gateways``: the vehicles of each
    gateway a ``gateway/...`` topic names (unknown ones: none)."""
    return shared_read_refusal(actor, topic, gateways or {})


def can_write(actor: Actor, topic: str) -> bool:
    return write_refusal(actor, topic) is None


def can_read(actor: Actor, topic: str, gateways: Gateways | None = None) -> bool:
    return read_refusal(actor, topic, gateways) is None


def check_write(actor: Actor, topics: str | list[str], as_vehicle: str | None = None) -> None:
    """``Forbidden`` naming the first topic ``actor`` (acting for ``as_vehicle``, when a
    gateway's op names one) may not write."""
    _check(lambda a, t: write_refusal(a, t, as_vehicle), actor, topics)


def check_read(actor: Actor, topics: str | list[str], gateways: Gateways | None = None) -> None:
    """``Forbidden`` naming the first topic ``actor`` may not read."""
    _check(lambda a, t: read_refusal(a, t, gateways), actor, topics)


def gateways_named(topics: list[str]) -> set[str]:
    """The gateways whose namespace ``topics`` read (their vehicles decide who may)."""
    return {t.split("/")[1] for t in topics if t.startswith("gateway/") and t.count("/") >= 2}


def _check(rule: Callable[[Actor, str], str | None], actor: Actor, topics: str | list[str]) -> None:
    """The first topic refused: ``Invalid`` when it names no topic at all, ``Forbidden``
    when ``actor`` may not; its detail names the field as validation does (``topic``,
    or ``topics.<i>`` in a list)."""
    named = [("topic", topics)] if isinstance(topics, str) else list(_indexed(topics))
    for field_name, topic in named:
        reason = rule(actor, topic)
        if reason is not None:
            said = f"{topic}: {reason}"  # the detail is a sentence that names the topic
            details = [{"field": field_name, "message": said}]
            if shape_problem(topic) is not None:
                raise Invalid(said, details=details)
            raise Forbidden(reason, details=details)


def _indexed(topics: list[str]) -> Iterator[tuple[str, str]]:
    for index, topic in enumerate(topics):
        yield f"topics.{index}", topic


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
            said = f"this token does not act for vehicle {vehicle_id}"
            raise Forbidden(said, details=[{"field": "vehicle_id", "message": said}])
        return UnitRef(f"vehicle:{vehicle_id}", "vehicle", parent=f"gateway:{actor.name}")
    if actor.kind == "vehicle":
        return UnitRef(f"vehicle:{actor.name}", "vehicle")
    if actor.kind == "gateway":
        return UnitRef(f"gateway:{actor.name}", "gateway")
    return UnitRef(f"user:{actor.name}", "operator")
