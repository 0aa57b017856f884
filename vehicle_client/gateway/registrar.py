"""A gateway's units' registrations sent up, each unit told once the server's ``routes``
push for its vehicle shows them.

The server answers a ``register`` before it pushes the routes that follow from it,
and the gateway forwards a unit's publish up only when that push says someone
above wants the topic (``forward_up``). A unit that publishes the moment its
register is acknowledged would be kept local, acknowledged ok and lost above: so
the unit's ack waits for the push (at most :data:`ROUTES_WAIT_S`). A topic a unit
publishes on without registering it is registered above first, the same way.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Iterable
from typing import Any

from fleet_protocol.ws import AckPush
from vehicle_client.errors import AgentError
from vehicle_client.gateway.forwarding import LocalUnit, TopicRouter
from vehicle_client.transport.ws import WsLink

#: How long a unit's register (or first publish on a topic) waits for its routes push.
ROUTES_WAIT_S = 2.0


class Registrar:
    def __init__(self, link: WsLink, router: TopicRouter) -> None:
        self.link = link
        self.router = router
        #: Registrations sent up, waiting for the ``routes`` push that shows them (one
        #: wait for a vehicle's topic, however many of its units register it at once).
        self._shown: dict[tuple[str, str], asyncio.Future[None]] = {}

    async def register(self, unit: LocalUnit, topics: list[str], op: dict[str, Any]) -> AckPush:
        """Send ``op`` up (a ``register`` of the topics among ``topics`` new to the unit's
        vehicle); once acknowledged, ``topics`` are taken on here for the unit, and the
        ack returned when the vehicle's routes push shows the topics sent up (or
        :data:`ROUTES_WAIT_S` passed). AgentError: the link."""
        loop = asyncio.get_running_loop()
        shown = {
            key: self._shown.setdefault(key, loop.create_future())
            for key in ((unit.vehicle_id, t) for t in dict.fromkeys(op["topics"]))
        }  # before the call: the push may be read before its ack is
        try:
            ack = await self.link.call(op, check=False)
            if ack.ok and unit in self.router.units:
                self.router.register(unit, topics)
                # The gateway's own routes come before the vehicle's: once the vehicle's
                # show the topics, forward_up says whether anyone above wants them.
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(asyncio.gather(*shown.values()), ROUTES_WAIT_S)
            return ack
        finally:
            for key, future in shown.items():
                if self._shown.get(key) is future:
                    del self._shown[key]

    async def before_publish(self, unit: LocalUnit, topic: str) -> None:
        """Register ``topic`` above for the unit if its vehicle publishes on it
        unregistered (the routing table there then says whether anyone outside wants
        it). Not when the link is down or the server refuses: it goes up then, as
        before registering."""
        if (
            unit not in self.router.units
            or self.router.produced(unit.vehicle_id, topic)
            or not self.link.connected
        ):
            return
        op = {"op": "register", "vehicle_id": unit.vehicle_id, "topics": [topic]}
        with contextlib.suppress(AgentError):
            await self.register(unit, [topic], op)

    def shown(self, vehicle_id: str, topics: Iterable[str]) -> None:
        """The vehicle's routes push came, showing ``topics`` among what it produces."""
        for topic in topics:
            waiting = self._shown.get((vehicle_id, topic))
            if waiting is not None and not waiting.done():
                waiting.set_result(None)
