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

Reading (every namespace has an owner):

- ``vehicle/<id>/...`` needs read access to that vehicle (a user assigned to
  it or an admin, the vehicle itself, a gateway listing it);
- ``user/<username>/...``: that user and admins; and a user's topic about a
  vehicle, ``user/<username>/<name>/<vehicle_id>[/...]`` (a cloud worker's
  results, the multilayer paper's offloading), also whoever may read that
  vehicle: that is how a worker's results reach the vehicle and its operators;
- ``gateway/<gateway_id>/...``: that gateway, its units (the vehicles it
  lists), whoever may read one of them, and admins;
- ``fleet`` is for users (the server filters presence per user), and ``zones``
  too (it says only that the zones changed: each reads its own again).

The caller is anything shaped like :class:`Actor` (``server.domain.access.Principal``
is). Unit identities for the routing table come from :func:`unit_for`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Literal, Protocol

from fleet_protocol.topics import SERVER_ONLY_VEHICLE_TOPICS, split_topic
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


class Actor(Protocol):
    """The authenticated caller, as far as topics care."""

    @property
    def kind(self) -> str: ...  # "user" | "vehicle" | "gateway"

    @property
    def name(self) -> str: ...

    @property
    def is_admin(self) -> bool: ...

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


def shape_problem(topic: str) -> str | None:
    """Why ``topic`` names no topic anybody may read or write (the same for every caller:
    a 422, not a refusal of rights); ``None`` for one of a known shape."""
    segments = split_topic(topic)
    namespace = segments[0]
    if namespace in ("fleet", "zones"):
        if len(segments) > 1:
            return f"there are no topics under '{namespace}/': '{namespace}' is one topic"
        return None
    if namespace not in ("vehicle", "user", "gateway"):
        return (
            f"there are no topics under '{namespace}/': a topic is fleet, zones, or under "
            "vehicle/<id>/, user/<username>/ or gateway/<id>/"
        )
    if len(segments) < 3:
        return f"a topic under '{namespace}/' is '{namespace}/<id>/<name>'"
    return None


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
    """Why ``actor`` may not subscribe to ``topic``; ``None`` if it may. ``gateways``: the
    vehicles of each gateway a ``gateway/...`` topic names (unknown ones: none)."""
    if (problem := shape_problem(topic)) is not None:
        return problem
    segments = split_topic(topic)
    namespace = segments[0]
    if namespace in ("fleet", "zones"):
        return None if actor.kind == "user" else f"'{namespace}' is for users"
    owner = segments[1]
    if namespace == "vehicle":
        return None if _reads_vehicle(actor, owner) else f"no read access to vehicle {owner}"
    if actor.is_admin:
        return None
    if namespace == "user":
        if actor.kind == "user" and actor.name == owner:
            return None
        if len(segments) >= 4 and _reads_vehicle(actor, segments[3]):
            return None  # a user's results about a vehicle its readers may read
        return f"only {owner} (and admins) read 'user/{owner}/', but for a vehicle's readers"
    units = (gateways or {}).get(owner, frozenset())
    if actor.kind == "gateway" and actor.name == owner:
        return None
    if any(_reads_vehicle(actor, vehicle_id) for vehicle_id in units):
        return None
    return f"only gateway {owner}, its units and their readers read 'gateway/{owner}/'"


def _reads_vehicle(actor: Actor, vehicle_id: str) -> bool:
    return actor.can_see(vehicle_id) or actor.acts_for(vehicle_id)


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
