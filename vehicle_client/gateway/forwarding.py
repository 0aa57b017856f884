"""What a gateway does with its local units' topics (the multilayer paper). Pure.

Local units (vehicles on the gateway's own WebSocket) register what they
produce and subscribe to what they need. The gateway:

- delivers a unit's publish to the other local units subscribed to it,
  at once, without the cloud;
- sends it **up** only if the topic is in its ``forward_up`` (the server's
  ``routes`` push to the gateway unit: topics produced under the gateway
  that a unit outside it consumes; demand-driven, so nothing travels up
  that nobody above asked for, and nothing its own units alone consume);
- delivers **down** an event from above to the local units subscribed to
  its topic (the server sends the gateway what is in its ``forward_down``).

Media frames (binary, on media topics) take the same routes; they are
counted apart (``media_up``, ``media_kept``) so that what a camera costs the
uplink can be read off the gateway.

Registrations and subscriptions are repeated upstream on the units' behalf
(ops with ``vehicle_id``), so the server's table holds them, and again after
every reconnection (:meth:`TopicRouter.replay`); a unit that leaves has both
taken back upstream. The gateway registers a topic a unit publishes on
unregistered before routing it (``UnitServer``); one it could not register
goes up (the table above has no demand for it to read).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from fleet_protocol.topics import SERVER_ONLY_VEHICLE_TOPICS, topic_owner
from fleet_protocol.ws import MAX_TOPICS_PER_OP


@dataclass
class _Unit:
    produces: set[str] = field(default_factory=set)
    #: topic -> the ``throttle_ms`` the unit asked (0: every event)
    consumes: dict[str, int] = field(default_factory=dict)


@dataclass
class Delivery:
    """Where a publish goes: these local units, and up or not."""

    local: list[str]
    up: bool


@dataclass
class TopicRouter:
    units: dict[str, _Unit] = field(default_factory=dict)
    forward_up: frozenset[str] = frozenset()
    forward_down: frozenset[str] = frozenset()
    sent_up: int = 0
    kept_local: int = 0
    media_up: int = 0
    media_kept: int = 0

    def add(self, vehicle_id: str) -> None:
        self.units.setdefault(vehicle_id, _Unit())

    def drop(self, vehicle_id: str) -> _Unit | None:
        """Forget a unit; what it had (to unregister upstream)."""
        return self.units.pop(vehicle_id, None)

    def register(self, vehicle_id: str, topics: list[str]) -> None:
        self.units[vehicle_id].produces.update(topics)

    def unregister(self, vehicle_id: str, topics: list[str]) -> None:
        self.units[vehicle_id].produces.difference_update(topics)

    def subscribe(self, vehicle_id: str, topics: list[str], throttle_ms: int = 0) -> None:
        self.units[vehicle_id].consumes.update(dict.fromkeys(topics, throttle_ms))

    def unsubscribe(self, vehicle_id: str, topics: list[str]) -> None:
        consumes = self.units[vehicle_id].consumes
        for topic in topics:
            consumes.pop(topic, None)

    def throttle_ms(self, vehicle_id: str, topic: str) -> int:
        """The ``throttle_ms`` the unit asked for ``topic`` (0: none, or not subscribed)."""
        unit = self.units.get(vehicle_id)
        return unit.consumes.get(topic, 0) if unit is not None else 0

    def subscribers(self, topic: str, *, but: str | None = None) -> list[str]:
        return sorted(v for v, u in self.units.items() if topic in u.consumes and v != but)

    def publish(self, vehicle_id: str, topic: str, *, media: bool = False) -> Delivery:
        """A local unit published on ``topic``: to whom (the caller checked the right).

        A topic the unit registered goes up on demand (``forward_up``); one it did not
        register is unknown to the routing table above, whose demand cannot be known
        here: it goes up, as a publish straight to the server reaches its subscribers."""
        unit = self.units.get(vehicle_id)
        up = topic in self.forward_up or unit is None or topic not in unit.produces
        if media and up:
            self.media_up += 1
        elif media:
            self.media_kept += 1
        elif up:
            self.sent_up += 1
        else:
            self.kept_local += 1
        return Delivery(self.subscribers(topic, but=vehicle_id), up)

    def from_above(self, topic: str, *, media: bool = False) -> list[str]:
        """An event came down from the cloud: the local units subscribed to it.

        The server filters a JSON event by the connection it came from, not a
        media frame: one on a topic of a unit connected here is this gateway's
        own frame coming back, which its units had already (none, then).
        """
        namespace, owner = topic_owner(topic)
        if media and namespace == "vehicle" and owner in self.units:
            return []
        return self.subscribers(topic)

    def routes(self, unit: str, forward_up: list[str], forward_down: list[str]) -> str | None:
        """A ``routes`` push: the gateway's own updates forwarding (``None`` back);
        a local unit's (``vehicle:<id>``) is for that unit: its vehicle id back."""
        if unit.startswith("gateway:"):
            self.forward_up, self.forward_down = frozenset(forward_up), frozenset(forward_down)
            return None
        kind, _, vehicle_id = unit.partition(":")
        return vehicle_id if kind == "vehicle" and vehicle_id in self.units else None

    def replay(self) -> list[dict[str, Any]]:
        """The ops to send after a reconnection: each unit's ``register`` and ``subscribe``
        (with the ``throttle_ms`` it asked), at most an op's worth of topics each."""
        ops: list[dict[str, Any]] = []
        for vehicle_id, unit in sorted(self.units.items()):
            for chunk in in_ops(unit.produces):
                ops.append({"op": "register", "vehicle_id": vehicle_id, "topics": chunk})
            by_throttle: dict[int, list[str]] = {}
            for topic, throttle_ms in unit.consumes.items():
                by_throttle.setdefault(throttle_ms, []).append(topic)
            for throttle_ms, topics in sorted(by_throttle.items()):
                for chunk in in_ops(topics):
                    op = {"op": "subscribe", "vehicle_id": vehicle_id, "topics": chunk}
                    ops.append({**op, "throttle_ms": throttle_ms} if throttle_ms else op)
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
