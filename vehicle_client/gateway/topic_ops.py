"""A local unit's topic ops (``register``, ``unregister``, ``subscribe``,
``unsubscribe``), and what they send up for its vehicle.

Several local units may act for one vehicle, each holding its own topics;
the server holds them for the vehicle (ops with ``vehicle_id``), once. So
an op of one unit goes up only for what it changes in what the vehicle's
units hold together (``TopicRouter.ops_for``), as the server itself counts
a unit's sockets:

- the first unit to subscribe to (or register) a topic sends it up, and is
  answered with the server's ack; a unit subscribing to a topic another unit
  of its vehicle holds already is answered here, at once;
- a topic is taken back above (``unsubscribe``, ``unregister``) only when the
  last unit of the vehicle holding it lets go of it or leaves;
- the vehicle is served each topic at the least ``throttle_ms`` its units
  asked: a change of that least one subscribes it again above, at the new one
  (the gateway holds each unit to what that unit asked, ``UnitQueue``);
- after a reconnection, the union goes up again (``TopicRouter.replay``).

A ``register`` or ``subscribe`` takes effect among the local units once the
server accepted it (refused: it leaves nothing to replay later), or at once
while the cloud link is down (acked with ``local_only``: a unit restarted at sea
still gets its neighbours' data; it goes up with the replay when the link is
back). A subscription the server refuses then is handed back to the caller
(``UnitServer``), which lets go of it and tells the units that held it.
An ``unsubscribe`` or ``unregister`` takes effect here at once. The ops of one
vehicle's units, and their leaving, take turns (a lock for each vehicle), so
that what is held here and what was said above never cross.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import defaultdict
from typing import Any

from fleet_protocol import ErrorBody
from fleet_protocol.ws import AckPush, RegisterOp, SubscribeOp, UnregisterOp, UnsubscribeOp
from vehicle_client.errors import AgentError
from vehicle_client.gateway.forwarding import LocalUnit, TopicRouter
from vehicle_client.gateway.registrar import Registrar
from vehicle_client.transport.ws import WsLink

__all__ = ["Dropped", "TopicOp", "TopicOps"]

log = logging.getLogger(__name__)

TopicOp = RegisterOp | UnregisterOp | SubscribeOp | UnsubscribeOp
#: A subscription refused above at the replay: its vehicle, its topic, the server's error.
Dropped = tuple[str, str, ErrorBody]


class TopicOps:
    def __init__(self, link: WsLink, router: TopicRouter, registrar: Registrar) -> None:
        self.link = link
        self.router = router
        self.registrar = registrar
        self._turns: defaultdict[str, asyncio.Lock] = defaultdict(asyncio.Lock)
        self._awaiting: dict[str, set[LocalUnit]] = {}

    async def take(self, unit: LocalUnit, op: TopicOp) -> tuple[AckPush, set[str]]:
        """Do ``op`` for ``unit``, sending up what it changes for the vehicle; the answer
        for the unit (its ``id`` the op's, empty when it had none), and the topics it
        subscribed above (the server follows its ack with their states)."""
        async with self._turns[unit.vehicle_id]:
            return await self._take_op(unit, op)

    def awaiting(self, topic: str) -> set[LocalUnit]:
        """The units whose subscription to ``topic`` is on its way up: the state the server
        sends after its ack is theirs (it may come before they are subscribed here)."""
        return self._awaiting.get(topic, set())

    async def join(self, unit: LocalUnit) -> None:
        """A unit connected. In its vehicle's turn: a named unit whose former
        connection is still being taken out (``gone``) starts afresh once that is
        through, rather than have what it takes on dropped under it."""
        async with self._turns[unit.vehicle_id]:
            self.router.add(unit)

    async def before_publish(self, unit: LocalUnit, topic: str) -> None:
        """A topic the unit's vehicle publishes on unregistered: registered above first."""
        async with self._turns[unit.vehicle_id]:
            await self.registrar.before_publish(unit, topic)

    async def _take_op(self, unit: LocalUnit, op: TopicOp) -> tuple[AckPush, set[str]]:
        upstream = self._upstream(unit, op)
        if isinstance(op, UnsubscribeOp):
            self.router.unsubscribe(unit, op.topics)
        elif isinstance(op, UnregisterOp):
            self.router.unregister(unit, op.topics)
        answer: dict[str, Any] = {"topics": op.topics}
        # The states the server sends after a subscribe's ack are the unit's from then on,
        # though it is subscribed here only once every op it needs is answered.
        up = {t for sent in upstream if sent["op"] == "subscribe" for t in sent["topics"]}
        for topic in up:
            self._awaiting.setdefault(topic, set()).add(unit)
        try:
            for sent in upstream:
                if sent["op"] == "register":
                    ack = await self.registrar.register(unit, op.topics, sent)
                else:
                    ack = await self.link.call(sent, check=False)
                if not ack.ok:
                    return ack.model_copy(update={"id": op.id or ""}), set()
            self._take(unit, op)
        except AgentError:
            self._take(unit, op)
            return AckPush.success(op.id or "", {**answer, "local_only": True}), set()
        finally:
            for topic in up:
                waiting = self._awaiting[topic]
                waiting.discard(unit)
                if not waiting:
                    del self._awaiting[topic]
        if not upstream and not self.link.connected:
            answer["local_only"] = True  # as the other unit's that holds it above
        return AckPush.success(op.id or "", answer), up

    def _upstream(self, unit: LocalUnit, op: TopicOp) -> list[dict[str, Any]]:
        """What ``op`` changes above for the unit's vehicle (``TopicRouter.ops_for``)."""
        held = self.router.units.get(unit)
        produces = set() if held is None else held.produces
        consumes = {} if held is None else held.consumes
        if isinstance(op, RegisterOp):
            return self.router.ops_for(unit, produces=produces | set(op.topics))
        if isinstance(op, UnregisterOp):
            return self.router.ops_for(unit, produces=produces - set(op.topics))
        if isinstance(op, SubscribeOp):
            asked = {**consumes, **dict.fromkeys(op.topics, op.throttle_ms)}
            return self.router.ops_for(unit, consumes=asked)
        kept = {t: ms for t, ms in consumes.items() if t not in op.topics}
        return self.router.ops_for(unit, consumes=kept)

    def _take(self, unit: LocalUnit, op: TopicOp) -> None:
        """A ``register`` or ``subscribe`` takes effect among the local units (the
        registrar took a register sent up on already: again changes nothing)."""
        if unit not in self.router.units:
            return
        if isinstance(op, RegisterOp):
            self.router.register(unit, op.topics)
        elif isinstance(op, SubscribeOp):
            self.router.subscribe(unit, op.topics, op.throttle_ms)

    async def gone(self, unit: LocalUnit) -> None:
        """A unit left: what only it held for its vehicle is taken back upstream too (else
        its registrations stay in the table above and count against the vehicle's
        bound); a topic its vehicle's other units still hold stays, at their least
        ``throttle_ms``."""
        async with self._turns[unit.vehicle_id]:
            upstream = self.router.ops_for(unit, produces=set(), consumes={})
            self.router.drop(unit)
            if not self.link.connected:
                return  # after a reconnection the replay leaves it out anyway
            for sent in upstream:
                with contextlib.suppress(AgentError):
                    await self.link.send(sent)

    async def replay(self) -> list[Dropped]:
        """After a reconnection: what each vehicle's units hold, once, the ops together
        (one round trip). The subscriptions the server refused, for the caller to let
        go of and tell their units (else each would go up again at every reconnection,
        its units hearing nothing)."""
        answered = await asyncio.gather(*(self._replayed(sent) for sent in self.router.replay()))
        return [each for one_op in answered for each in one_op]

    async def _replayed(self, sent: dict[str, Any]) -> list[Dropped]:
        """``sent`` acked; the subscriptions of it the server refused. The server refuses
        an op whole for its first topic it may not read: a ``forbidden`` op of several
        topics is sent again one topic each, so that the others still go up."""
        try:
            ack = await self.link.call(sent, check=False)
        except AgentError:
            return []  # the link is down again: the next replay
        if ack.ok:
            return []
        error = ack.error or ErrorBody(code="forbidden", message="refused")
        topics: list[str] = sent["topics"]
        subscribe = sent["op"] == "subscribe"
        if subscribe and len(topics) > 1 and error.code == "forbidden":
            ones = await asyncio.gather(*(self._replayed({**sent, "topics": [t]}) for t in topics))
            return [each for one in ones for each in one]
        what = f"{sent['op']} {', '.join(topics)} for {sent['vehicle_id']}"
        log.warning("%s: refused at the replay: %s", what, error.message)
        return [(sent["vehicle_id"], topic, error) for topic in topics] if subscribe else []
