"""The routing table of the multilayer publish-subscribe interface. Pure.

Units (vehicles, gateways, processing workers, operators) register the
topics they produce and subscribe to the topics they need, at any time. A
unit may sit under a gateway (its ``parent``), gateways under gateways; the
unit without a parent is the one holding the connection to the cloud (its
*endpoint*).

The table answers three questions:

- **Who receives a publish**: :meth:`RoutingTable.subscribers` (exactly the
  units subscribed to the topic), and :meth:`RoutingTable.recipients`, the
  endpoints the cloud sends it to: a unit served through the same endpoint
  as the publisher got it from its gateway already.
- **What each unit is told** (its ``routes`` push): :meth:`RoutingTable.view`,
  only the part the unit takes part in (its topics with their consumers or
  producers, and a gateway's forwarding) -- never the whole table, which
  grows with the square of the fleet.
- **What changed**: every mutation returns the ids of the units whose view
  changed, so ``routes`` goes to those alone.

Gateway forwarding is demand-driven. A gateway forwards *upward* a topic
produced in its subtree only when a unit outside the subtree subscribed to
it and no unit inside did (the contract and the multilayer paper: what its
own units consume is served locally and stays there, and nothing travels up
that nobody above asked for); it forwards *downward* the topics units below
it subscribed to. Forwarding upward needs the producer to have registered the
topic; the paper registers before it publishes.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any, Literal

from server.errors import Conflict, Invalid, NotFound

__all__ = ["DEFAULT_MAX_TOPICS_PER_UNIT", "RoutingTable", "UnitKind", "UnitView"]

UnitKind = Literal["vehicle", "gateway", "worker", "operator"]
DEFAULT_MAX_TOPICS_PER_UNIT = 256


@dataclass(frozen=True)
class UnitView:
    """The part of the table one unit takes part in (the ``routes`` push's body)."""

    unit: str
    #: Each topic the unit registered, with the units subscribed to it.
    produces: dict[str, tuple[str, ...]] = field(default_factory=dict)
    #: Each topic the unit subscribed to, with the units that registered it.
    consumes: dict[str, tuple[str, ...]] = field(default_factory=dict)
    #: Gateways: the topics they send up to the cloud.
    forward_up: tuple[str, ...] = ()
    #: Gateways: the topics they deliver from above to their units.
    forward_down: tuple[str, ...] = ()

    def as_dict(self) -> dict[str, Any]:
        """Fields for ``fleet_protocol.ws.RoutesPush(**view.as_dict())``."""
        return {
            "unit": self.unit,
            "produces": {t: list(u) for t, u in self.produces.items()},
            "consumes": {t: list(u) for t, u in self.consumes.items()},
            "forward_up": list(self.forward_up),
            "forward_down": list(self.forward_down),
        }


@dataclass
class _Unit:
    id: str
    kind: UnitKind
    parent: str | None
    produces: set[str] = field(default_factory=set)
    consumes: set[str] = field(default_factory=set)
    children: set[str] = field(default_factory=set)
    bounded: bool = True  # held to max_topics_per_unit


class RoutingTable:
    """Units, what they produce and consume, and who must hear of a change."""

    def __init__(self, max_topics_per_unit: int = DEFAULT_MAX_TOPICS_PER_UNIT) -> None:
        self.max_topics_per_unit = max_topics_per_unit
        self._units: dict[str, _Unit] = {}
        self._producers: dict[str, set[str]] = {}
        self._consumers: dict[str, set[str]] = {}
        #: Counts the changes of who produces and consumes what (for what is worked out
        #: from the table: it is worked out again when this moved).
        self.version = 0

    # -- units ----------------------------------------------------------------

    def add_unit(
        self, unit_id: str, kind: UnitKind, parent: str | None = None, *, bounded: bool = True
    ) -> None:
        """Add a unit (no topics yet: no one else's view changes). Idempotent.
        ``bounded``: held to ``max_topics_per_unit`` (not: a stand-in for many units)."""
        existing = self._units.get(unit_id)
        if existing is not None:
            if (existing.kind, existing.parent) != (kind, parent):
                raise Conflict(
                    f"unit {unit_id} is already in the table as a {existing.kind}"
                    + (f" under {existing.parent}" if existing.parent else "")
                )
            return
        if parent is not None:
            gateway = self._units.get(parent)
            if gateway is None or gateway.kind != "gateway":
                raise NotFound(f"no gateway unit {parent} to put {unit_id} under")
            gateway.children.add(unit_id)
        self._units[unit_id] = _Unit(unit_id, kind, parent, bounded=bounded)

    def remove_unit(self, unit_id: str) -> frozenset[str]:
        """Remove a unit, its topics and the units under it; the remaining units affected."""
        unit = self._unit(unit_id)
        removed = list(self._subtree(unit_id))
        changed: set[str] = set()
        for member in removed:
            changed |= self.unsubscribe(member, list(self._units[member].consumes))
            changed |= self.unregister(member, list(self._units[member].produces))
        if unit.parent is not None:
            self._units[unit.parent].children.discard(unit_id)
        for member in removed:
            del self._units[member]
        return frozenset(changed - set(removed))

    def __contains__(self, unit_id: object) -> bool:
        return unit_id in self._units

    def units(self) -> frozenset[str]:
        return frozenset(self._units)

    def parent(self, unit_id: str) -> str | None:
        return self._unit(unit_id).parent

    def endpoint(self, unit_id: str) -> str:
        """The unit holding the connection this unit is reached through (itself, or
        its topmost gateway)."""
        unit = self._unit(unit_id)
        while unit.parent is not None:
            unit = self._units[unit.parent]
        return unit.id

    # -- topics ---------------------------------------------------------------

    def register(self, unit_id: str, topics: Iterable[str]) -> frozenset[str]:
        """``unit_id`` produces ``topics`` (besides what it did); the units whose view changed."""
        return self._change(unit_id, topics, produce=True, add=True)

    def unregister(self, unit_id: str, topics: Iterable[str]) -> frozenset[str]:
        return self._change(unit_id, topics, produce=True, add=False)

    def subscribe(self, unit_id: str, topics: Iterable[str]) -> frozenset[str]:
        """``unit_id`` consumes ``topics`` (besides what it did); the units whose view changed."""
        return self._change(unit_id, topics, produce=False, add=True)

    def unsubscribe(self, unit_id: str, topics: Iterable[str]) -> frozenset[str]:
        return self._change(unit_id, topics, produce=False, add=False)

    def consumes_of(self, unit_id: str) -> frozenset[str]:
        """The topics ``unit_id`` subscribes to."""
        return frozenset(self._unit(unit_id).consumes)

    def consumed(self) -> frozenset[str]:
        """Every topic some unit subscribes to."""
        return frozenset(self._consumers)

    def subscribers(self, topic: str) -> frozenset[str]:
        """Exactly the units subscribed to ``topic``."""
        return frozenset(self._consumers.get(topic, ()))

    def producers(self, topic: str) -> frozenset[str]:
        return frozenset(self._producers.get(topic, ()))

    def recipients(self, topic: str, source: str | None = None) -> frozenset[str]:
        """The endpoints the cloud sends a publish on ``topic`` to.

        ``source`` is the publishing unit (``None``: the server or another
        replica). Subscribers reached through the publisher's own endpoint are
        left out: their gateway delivered it locally (and a unit never gets
        its own publish back).
        """
        endpoints = {self.endpoint(u) for u in self._consumers.get(topic, ())}
        if source is not None:
            endpoints.discard(self.endpoint(source))
        return frozenset(endpoints)

    def forward_up(self, gateway_id: str) -> frozenset[str]:
        """Topics produced under (or by) the gateway that a unit outside it consumes and
        none inside it does (the contract: what its own units consume stays below)."""
        inside = set(self._subtree(gateway_id))
        produced = {t for member in inside for t in self._units[member].produces}
        return frozenset(
            t
            for t in produced
            if (consumers := self._consumers.get(t, set())) and not consumers & inside
        )

    def forward_down(self, gateway_id: str) -> frozenset[str]:
        """Topics units under the gateway consume."""
        below = set(self._subtree(gateway_id)) - {gateway_id}
        return frozenset(t for member in below for t in self._units[member].consumes)

    def view(self, unit_id: str) -> UnitView:
        """What ``unit_id``'s ``routes`` push says."""
        unit = self._unit(unit_id)
        produces = {
            t: tuple(sorted(self._consumers.get(t, set()) - {unit_id}))
            for t in sorted(unit.produces)
        }
        consumes = {
            t: tuple(sorted(self._producers.get(t, set()) - {unit_id}))
            for t in sorted(unit.consumes)
        }
        if unit.kind != "gateway":
            return UnitView(unit_id, produces, consumes)
        return UnitView(
            unit_id,
            produces,
            consumes,
            tuple(sorted(self.forward_up(unit_id))),
            tuple(sorted(self.forward_down(unit_id))),
        )

    # -- internals ------------------------------------------------------------

    def _unit(self, unit_id: str) -> _Unit:
        unit = self._units.get(unit_id)
        if unit is None:
            raise NotFound(f"unit {unit_id} is not in the routing table")
        return unit

    def _subtree(self, unit_id: str) -> Iterator[str]:
        stack = [unit_id]
        while stack:
            current = stack.pop()
            yield current
            stack.extend(self._units[current].children)

    def _ancestors(self, unit_id: str) -> Iterator[str]:
        parent = self._units[unit_id].parent
        while parent is not None:
            yield parent
            parent = self._units[parent].parent

    def _change(
        self, unit_id: str, topics: Iterable[str], *, produce: bool, add: bool
    ) -> frozenset[str]:
        unit = self._unit(unit_id)
        mine = unit.produces if produce else unit.consumes
        topics = set(topics)
        delta = topics - mine if add else topics & mine
        if not delta:
            return frozenset()
        self.version += 1
        if add and unit.bounded and len(mine) + len(delta) > self.max_topics_per_unit:
            verb = "registers" if produce else "subscribes to"
            message = (
                f"a unit {verb} at most {self.max_topics_per_unit} topics"
                f" ({unit_id} has {len(mine)}, {len(delta)} more asked)"
            )
            details = [{"field": "topics", "message": message}]
            raise Invalid(message, code="too_many_topics", details=details)
        # Whose view can this change: the unit, its gateways, and the units on
        # the other side of each topic (their lists name this unit). A
        # subscription also moves the forward_up of the producers' gateways.
        other_side = self._consumers if produce else self._producers
        candidates = {unit_id, *self._ancestors(unit_id)}
        for topic in delta:
            for other in other_side.get(topic, ()):
                candidates.add(other)
                if not produce:
                    candidates.update(self._ancestors(other))
        before = {c: self.view(c) for c in candidates}

        index = self._producers if produce else self._consumers
        for topic in delta:
            if add:
                mine.add(topic)
                index.setdefault(topic, set()).add(unit_id)
            else:
                mine.discard(topic)
                holders = index[topic]
                holders.discard(unit_id)
                if not holders:
                    del index[topic]
        return frozenset(c for c in candidates if self.view(c) != before[c])
