"""What a gateway does with its local units' topics (the multilayer paper). Pure.

Local units (vehicles on the gateway's own WebSocket) register what they
produce and subscribe to what they need. The gateway:

- delivers a unit's publish to the other local units subscribed to it,
  at once, without the cloud;
- sends it **up** only if no local unit consumes it and the topic is in its
  ``forward_up`` (the server's ``routes`` push to the gateway unit: topics
  produced under the gateway that a unit outside it consumes and none
  inside does; demand-driven, so nothing travels up that nobody above asked
  for, and nothing its own units consume: the contract's rule);
- delivers **down** an event from above to the local units subscribed to
  its topic (the server sends the gateway what is in its ``forward_down``).

Media frames (binary, on media topics) take the same routes; they are
counted apart (``media_up``, ``media_kept``) so that what a camera costs the
uplink can be read off the gateway.

A unit is a :class:`LocalUnit`: one connection, acting for one vehicle;
several may act for the same one (a sonar driver, a camera, a mission
script), each with its own registrations and subscriptions. The table above
knows only the vehicle (ops with ``vehicle_id``), so what goes up is what the
vehicle's units hold together (:class:`Held`: the topics any of them
registers, the topics any of them subscribes to at the least ``throttle_ms``
they asked): :meth:`TopicRouter.ops_for` gives the ops that a change of one
unit makes to it (a topic subscribed above once, by the first unit; taken
back above by the last one; subscribed again when the least throttle
changes), and :meth:`TopicRouter.replay` the whole of it after every
reconnection. The gateway registers a topic a unit publishes on
unregistered before routing it (``UnitServer``); one it could not register
goes up (the table above has no demand for it to read).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from fleet_protocol.topics import SERVER_ONLY_VEHICLE_TOPICS, Kept, is_media_topic, topic_owner
from fleet_protocol.topics import read_refusal as shared_read_refusal
from fleet_protocol.ws import MAX_TOPICS_PER_OP

#: What a gateway keeps of its topics' states at most; the topics written longest ago go.
MAX_KEPT_BYTES = 4 * 1024 * 1024


@dataclass(frozen=True, order=True)
class LocalUnit:
    """One local unit: the vehicle it acts for, and its name (the one it gave with
    ``?unit=``, or ``#<n>`` for a connection that gave none: a unit of its own)."""

    vehicle_id: str
    name: str

    def __str__(self) -> str:
        return f"{self.vehicle_id}/{self.name}"


@dataclass
class _Unit:
    produces: set[str] = field(default_factory=set)
    #: topic -> the ``throttle_ms`` the unit asked (0: every event)
    consumes: dict[str, int] = field(default_factory=dict)


@dataclass
class Held:
    """What a vehicle's local units hold together, as the table above holds it."""

    produces: set[str] = field(default_factory=set)
    #: topic -> the least ``throttle_ms`` its units asked
    consumes: dict[str, int] = field(default_factory=dict)

    def add(self, unit: _Unit) -> None:
        self.produces |= unit.produces
        for topic, throttle_ms in unit.consumes.items():
            self.consumes[topic] = min(throttle_ms, self.consumes.get(topic, throttle_ms))


@dataclass
class Delivery:
    """Where a publish goes: these local units, and up or not."""

    local: list[LocalUnit]
    up: bool


@dataclass
class TopicRouter:
    units: dict[LocalUnit, _Unit] = field(default_factory=dict)
    forward_up: frozenset[str] = frozenset()
    forward_down: frozenset[str] = frozenset()
    sent_up: int = 0
    kept_local: int = 0
    media_up: int = 0
    media_kept: int = 0

    def add(self, unit: LocalUnit) -> None:
        self.units.setdefault(unit, _Unit())

    def drop(self, unit: LocalUnit) -> _Unit | None:
        """Forget a unit; what it had."""
        return self.units.pop(unit, None)

    def register(self, unit: LocalUnit, topics: list[str]) -> None:
        self.units[unit].produces.update(topics)

    def unregister(self, unit: LocalUnit, topics: list[str]) -> None:
        self.units[unit].produces.difference_update(topics)

    def subscribe(self, unit: LocalUnit, topics: list[str], throttle_ms: int = 0) -> None:
        self.units[unit].consumes.update(dict.fromkeys(topics, throttle_ms))

    def unsubscribe(self, unit: LocalUnit, topics: list[str]) -> None:
        consumes = self.units[unit].consumes
        for topic in topics:
            consumes.pop(topic, None)

    def throttle_ms(self, unit: LocalUnit, topic: str) -> int:
        """The ``throttle_ms`` the unit asked for ``topic`` (0: none, or not subscribed)."""
        held = self.units.get(unit)
        return held.consumes.get(topic, 0) if held is not None else 0

    def of_vehicle(self, vehicle_id: str) -> list[LocalUnit]:
        """The local units acting for ``vehicle_id``."""
        return sorted(u for u in self.units if u.vehicle_id == vehicle_id)

    def held(self, vehicle_id: str) -> Held:
        """What the units of ``vehicle_id`` hold together (what the table above holds)."""
        held = Held()
        for unit, own in self.units.items():
            if unit.vehicle_id == vehicle_id:
                held.add(own)
        return held

    def produced(self, vehicle_id: str, topic: str) -> bool:
        """Whether a unit of ``vehicle_id`` registered ``topic`` (so did the vehicle above)."""
        units = self.units.items()
        return any(u.vehicle_id == vehicle_id and topic in held.produces for u, held in units)

    def ops_for(
        self,
        unit: LocalUnit,
        *,
        produces: set[str] | None = None,
        consumes: dict[str, int] | None = None,
    ) -> list[dict[str, Any]]:
        """The ops that tell the server what changes for the unit's vehicle if ``unit``
        came to hold ``produces`` and ``consumes`` (``None``: what it holds now) instead:
        none for a topic another unit of the vehicle holds as well, a ``subscribe``
        again where the least ``throttle_ms`` changes. Nothing is changed here."""
        own = self.units.get(unit, _Unit())
        before = self.held(unit.vehicle_id)
        after = Held()
        for other, theirs in self.units.items():
            if other.vehicle_id == unit.vehicle_id and other != unit:
                after.add(theirs)
        after.add(
            _Unit(
                own.produces if produces is None else produces,
                own.consumes if consumes is None else consumes,
            )
        )
        return changes(unit.vehicle_id, before, after)

    def subscribers(self, topic: str, *, but: LocalUnit | None = None) -> list[LocalUnit]:
        return sorted(u for u, held in self.units.items() if topic in held.consumes and u != but)

    def publish(self, unit: LocalUnit, topic: str, *, media: bool = False) -> Delivery:
        """A local unit published on ``topic``: to whom (the caller checked the right).

        A topic a local unit consumes stays here (the contract: a gateway forwards up
        what its own units do not consume), whatever ``forward_up`` says before the
        table above hears of that subscription. Else a topic the unit's vehicle
        registered goes up on demand (``forward_up``); one it did not register is
        unknown to the routing table above, whose demand cannot be known here: it goes
        up, as a publish straight to the server reaches its subscribers. The other
        units of the same vehicle get it as any other unit."""
        local = self.subscribers(topic, but=unit)
        up = not local and (topic in self.forward_up or not self.produced(unit.vehicle_id, topic))
        if media and up:
            self.media_up += 1
        elif media:
            self.media_kept += 1
        elif up:
            self.sent_up += 1
        else:
            self.kept_local += 1
        return Delivery(local, up)

    def from_above(self, topic: str, *, media: bool = False) -> list[LocalUnit]:
        """An event came down from the cloud: the local units subscribed to it.

        The server filters a JSON event by the connection it came from, not a
        media frame: one on a topic of a vehicle with a unit connected here is
        this gateway's own frame coming back, which its units had already (none,
        then).
        """
        namespace, owner = topic_owner(topic)
        if media and namespace == "vehicle" and any(u.vehicle_id == owner for u in self.units):
            return []
        return self.subscribers(topic)

    def routes(self, unit: str, forward_up: list[str], forward_down: list[str]) -> str | None:
        """A ``routes`` push: the gateway's own updates forwarding (``None`` back); a
        vehicle's (``vehicle:<id>``) is for that vehicle's local units: its id back
        while it has one here."""
        if unit.startswith("gateway:"):
            self.forward_up, self.forward_down = frozenset(forward_up), frozenset(forward_down)
            return None
        kind, _, vehicle_id = unit.partition(":")
        here = any(u.vehicle_id == vehicle_id for u in self.units)
        return vehicle_id if kind == "vehicle" and here else None

    def replay(self) -> list[dict[str, Any]]:
        """The ops to send after a reconnection: for each vehicle, what its units hold
        together (each topic once, subscribed at the least ``throttle_ms`` they asked)."""
        vehicles = sorted({u.vehicle_id for u in self.units})
        return [op for v in vehicles for op in changes(v, Held(), self.held(v))]


def changes(vehicle_id: str, before: Held, after: Held) -> list[dict[str, Any]]:
    """The ops that take the table above from ``before`` to ``after`` for the vehicle:
    ``register``, ``subscribe`` (one for each ``throttle_ms``), ``unsubscribe``,
    ``unregister``, at most an op's worth of topics each."""
    ops: list[dict[str, Any]] = []

    def add(kind: str, topics: Iterable[str], **extra: Any) -> None:
        for chunk in in_ops(topics):
            ops.append({"op": kind, "vehicle_id": vehicle_id, "topics": chunk, **extra})

    add("register", after.produces - before.produces)
    by_throttle: dict[int, list[str]] = {}
    for topic, throttle_ms in after.consumes.items():
        if before.consumes.get(topic) != throttle_ms:
            by_throttle.setdefault(throttle_ms, []).append(topic)
    for throttle_ms, topics in sorted(by_throttle.items()):
        add("subscribe", topics, **({"throttle_ms": throttle_ms} if throttle_ms else {}))
    add("unsubscribe", before.consumes.keys() - after.consumes.keys())
    add("unregister", before.produces - after.produces)
    return ops


def in_ops(topics: Iterable[str]) -> list[list[str]]:
    """``topics``, sorted, in lists of at most ``MAX_TOPICS_PER_OP`` (what one op takes)."""
    ordered = sorted(topics)
    return [ordered[i : i + MAX_TOPICS_PER_OP] for i in range(0, len(ordered), MAX_TOPICS_PER_OP)]


def write_refusal(vehicle_id: str, topic: str) -> str | None:
    """Why the local unit ``vehicle_id`` may not publish or register ``topic`` (``None``: it may).

    The same rule the server applies upstream, checked here too because a
    publish kept local never reaches the server.
    """
    namespace, owner = topic_owner(topic)
    parts = topic.split("/")
    if namespace != "vehicle" or owner != vehicle_id or len(parts) < 3:
        return f"unit {vehicle_id} writes only under vehicle/{vehicle_id}/ (not {topic})"
    if parts[2] in SERVER_ONLY_VEHICLE_TOPICS:
        return f"{topic} is written by the server alone"
    return None


@dataclass(frozen=True)
class GatewayToken:
    """The gateway's token as a reader of topics (:class:`fleet_protocol.topics.Reader`):
    the vehicles it acts for (``None``: not known yet); its own id is not known here."""

    acts_for: frozenset[str] | None
    kind: str = "gateway"
    name: str = ""
    is_admin: bool = False

    def reads_vehicle(self, vehicle_id: str) -> bool | None:
        return None if self.acts_for is None else vehicle_id in self.acts_for


def read_refusal(topic: str, acts_for: frozenset[str] | None) -> str | None:
    """Why the gateway may not subscribe to ``topic`` for its units, as far as it can
    tell here (``None``: it may, or the server alone can tell); ``acts_for``: the
    vehicles its token acts for (``None``: not known yet). The server's rule
    (:func:`fleet_protocol.topics.read_refusal`), checked here because a subscription
    taken while the link is down is acked ``local_only`` and refused above only later,
    where its unit no longer hears of it. Who reads ``gateway/<id>/...`` depends on
    that gateway's vehicles, which the server alone knows."""
    return shared_read_refusal(GatewayToken(acts_for), topic, None)


def has_state(topic: str) -> bool:
    """Whether a topic's latest message is its state, given to a new subscriber (as the
    server keeps it): a topic a vehicle, a user or a gateway writes, not media. A topic
    the server writes has a state the server alone builds."""
    namespace, _ = topic_owner(topic)
    if namespace in ("fleet", "zones") or is_media_topic(topic):
        return False
    parts = topic.split("/")
    return not (
        namespace == "vehicle" and len(parts) >= 3 and parts[2] in SERVER_ONLY_VEHICLE_TOPICS
    )


class LatestKept:
    """Each topic's latest message as the gateway's units got it (from above, or from a
    sibling below): its state for a unit that subscribes later, answered here (its
    vehicle holds the topic above already, or the link is down). Kept as the server keeps
    states (``fleet_protocol.topics.Kept``: ``KEEP_MAX_BYTES`` a message), ``max_bytes``
    in all; only the topics that :func:`has_state`."""

    def __init__(self, max_bytes: int = MAX_KEPT_BYTES) -> None:
        self._kept: Kept[Any] = Kept(max_bytes)

    def note(self, topic: str, message: Any, size: int) -> None:
        """``message`` (what is handed back) is ``topic``'s latest, ``size`` bytes of JSON."""
        if has_state(topic):
            self._kept.put(topic, message, size)

    def latest(self, topic: str) -> Any | None:
        return self._kept.get(topic)
