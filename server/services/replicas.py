"""Several replicas: the store is the truth, each replica's memory a cache of it.

With ``FLEET_REDIS_URL`` set, a replica that changes an instance's commands,
lease or record writes the change to the store first, then announces it on
the bus topic ``_state`` (``{origin, instance_id, part}``, part one of
``instance``, ``lease``, ``commands``). The other replicas re-read that part
from the store if they keep a copy of it. An announcement only tells a
replica to look again: lose one (Redis down) and a replica acts on its copy
until it next reads the store, which the services do before every decision
that matters (submit, take, grant, revoke, presence changes), and when the
bus comes back after an outage a replica reads back everything it holds.
See docs/live.md, "Several replicas".
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from server.bus import Bus, Message, Subscription

if TYPE_CHECKING:
    from server.services.commands import CommandService
    from server.services.control import ControlService
    from server.services.instances import InstanceService

log = logging.getLogger("fleet.replicas")

#: ``announce(instance_id, part)``: the part of an instance's state just written to the store.
Announce = Callable[[str, str], None]
STATE_TOPIC = "_state"
PARTS = ("instance", "lease", "commands")
#: How often the sync looks whether the bus came back (then it reads everything back).
HEALTH_CHECK_S = 0.5


def no_announce(instance_id: str, part: str) -> None:
    """One replica: nobody else to tell."""


class ReplicaSync:
    """Tells the other replicas what changed here, and refreshes what changed there."""

    def __init__(
        self,
        bus: Bus,
        instances: InstanceService,
        control: ControlService,
        commands: CommandService,
    ) -> None:
        self.bus = bus
        self.instances = instances
        self.control = control
        self.commands = commands
        self.origin = secrets.token_hex(8)
        self._pending: dict[str, set[str]] = {}
        self._wake = asyncio.Event()
        self._tasks: set[asyncio.Task[Any]] = set()
        self._worker: asyncio.Task[None] | None = None
        self._sub: Subscription | None = None
        self._stopped = False

    async def start(self) -> None:
        for service in (self.instances, self.control, self.commands):
            service.announce = self.announce
        self._sub = await self.bus.subscribe(STATE_TOPIC, self._on_message)
        self._worker = asyncio.create_task(self._run(), name="replica-sync")

    async def stop(self) -> None:
        self._stopped = True
        if self._sub is not None:
            await self.bus.unsubscribe(self._sub)
        for task in [self._worker, *self._tasks]:
            if task is not None:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task

    def announce(self, instance_id: str, part: str) -> None:
        if self._stopped:
            return
        message = {"origin": self.origin, "instance_id": instance_id, "part": part}
        task = asyncio.ensure_future(self.bus.publish(STATE_TOPIC, message))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def _on_message(self, _topic: str, message: Message) -> None:
        if not isinstance(message, dict) or message.get("origin") == self.origin:
            return
        instance_id, part = message.get("instance_id"), message.get("part")
        if isinstance(instance_id, str) and part in PARTS:
            self._pending.setdefault(instance_id, set()).add(str(part))
            self._wake.set()

    async def _run(self) -> None:
        healthy = self.bus.healthy
        while True:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._wake.wait(), HEALTH_CHECK_S)
            self._wake.clear()
            if self.bus.healthy and not healthy:  # announcements were lost meanwhile
                self._catch_up_all()
            healthy = self.bus.healthy
            while self._pending:  # one pass per instance, however many announcements came
                instance_id = next(iter(self._pending))
                parts = self._pending.pop(instance_id)
                try:
                    await self._refresh(instance_id, parts)
                except Exception:
                    log.exception("refreshing instance %s from the store failed", instance_id)

    def _catch_up_all(self) -> None:
        held = {s.instance_id for s in self.instances.live()}
        held.update(self.commands.lane_ids, self.control.lease_ids)
        log.info("bus back: reading %d instances back from the store", len(held))
        for instance_id in held:
            self._pending.setdefault(instance_id, set()).update(PARTS)

    def _holds(self, instance_id: str) -> bool:
        """Whether this replica keeps a copy of anything of the instance."""
        return (
            self.instances.current_by_id(instance_id) is not None
            or instance_id in self.commands.lane_ids
            or instance_id in self.control.lease_ids
        )

    async def _refresh(self, instance_id: str, parts: set[str]) -> None:
        if not self._holds(instance_id):
            return  # nothing here to catch up: what it reads later comes from the store
        if "instance" in parts and await self.instances.refresh(instance_id):
            self.commands.forget(instance_id)  # finished on another replica
            self.control.forget(instance_id)
            return
        if "lease" in parts:
            await self.control.refresh(instance_id, only_cached=True)
        if "commands" in parts:
            await self.commands.refresh(instance_id)
