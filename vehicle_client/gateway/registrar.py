"""A gateway's units' registrations sent up, each unit told once the server's ``routes``
push shows them.

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
from vehicle_client.gateway.forwarding import TopicRouter
from vehicle_client.transport.ws import WsLink

#: How long a unit's register (or first publish on a topic) waits for its routes push.
ROUTES_WAIT_S = 2.0


class Registrar:
    def __init__(self, link: WsLink, router: TopicRouter) -> None:
        self.link = link
        self.router = router
        #: Registrations sent up, waiting for the ``routes`` push that shows them.
        self._shown: dict[tuple[str, str], asyncio.Future[None]] = {}

    async def register(self, vehicle_id: str, topics: list[str], op: dict[str, Any]) -> AckPush:
        """Send the unit's ``register`` op up; once acknowledged, taken on here, and the
        ack returned when the unit's routes push shows the topics new to it (or
        :data:`ROUTES_WAIT_S` passed). AgentError: the link."""
        unit = self.router.units.get(vehicle_id)
        loop = asyncio.get_running_loop()
        shown = {
            (vehicle_id, t): loop.create_future()
            for t in dict.fromkeys(topics)
            if unit is not None and t not in unit.produces
        }
        self._shown.update(shown)  # before the call: the push may be read before its ack is
        try:
            ack = await self.link.call(op, check=False)
            if ack.ok and vehicle_id in self.router.units:
                self.router.register(vehicle_id, topics)
                # The gateway's own routes come before the unit's: once the unit's show
                # the topics, forward_up says whether anyone above wants them.
                if shown:
                    with contextlib.suppress(TimeoutError):
                        await asyncio.wait_for(asyncio.gather(*shown.values()), ROUTES_WAIT_S)
            return ack
        finally:
            for key, future in shown.items():
                if self._shown.get(key) is future:
                    del self._shown[key]

    async def before_publish(self, vehicle_id: str, topic: str) -> None:
        """Register ``topic`` above for the unit if it publishes on it unregistered (the
        routing table there then says whether anyone outside wants it). Not when the
        link is down or the server refuses: it goes up then, as before registering."""
        unit = self.router.units.get(vehicle_id)
        if unit is None or topic in unit.produces or not self.link.connected:
            return
        op = {"op": "register", "vehicle_id": vehicle_id, "topics": [topic]}
        with contextlib.suppress(AgentError):
            await self.register(vehicle_id, [topic], op)

    def shown(self, vehicle_id: str, topics: Iterable[str]) -> None:
        """The unit's routes push came, showing ``topics`` among what it produces."""
        for topic in topics:
            waiting = self._shown.get((vehicle_id, topic))
            if waiting is not None and not waiting.done():
                waiting.set_result(None)
