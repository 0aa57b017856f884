"""What keeps this replica's copies in step with the store when others write to it.

Whoever writes a part of an instance's state to the store (its record, its
lease, its commands) emits :class:`~server.domain.events.StateWritten`; this
sends it on the bus topic ``_state`` (``{origin, instance_id, part}``; part
``watch``: its watch state, which a replica drops, to read it again); a vehicle's
failsafe policy set goes on ``_policy`` (``{origin, vehicle_id}``), a change of the
zones on ``_zones`` (``{origin, version}``). A replica that hears another's
announcement reads that part back from the store, if it keeps a copy of it; on a
policy or the zones, it reads them and judges the vehicles' alarms again
(:meth:`~server.services.safety.SafetyService.judge_again`, as the replica that made
the change did). Revoked tokens travel the same way on
``_auth`` (``{origin, digests, token_ids, revoked}``; ``revoked`` false: their
user's rights changed): every replica drops them from its cache and closes the
sockets it holds for them.

An announcement only tells a replica to look again: lose one (Redis down)
and a replica acts on its copy until it next reads the store, which the
services do before every decision that matters (submit, take, grant,
revoke, presence changes). When the bus comes back after an outage a
replica reads back everything it holds and forgets its cached tokens.

With one process the bus is local: what this replica announces it hears
itself, and skips. One replica or many, the same code runs.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
from typing import Any

from server.bus import Bus, Message, Subscription
from server.domain.events import FailsafeChanged, StateWritten, TokensRevoked, ZonesChanged
from server.services.auth import AuthService
from server.services.commands import CommandService
from server.services.control import ControlService
from server.services.dead_letters import DeadLetters
from server.services.instances import InstanceService
from server.services.messagebus import MessageBus
from server.services.safety import SafetyService

log = logging.getLogger("fleet.replicas")

STATE_TOPIC = "_state"
AUTH_TOPIC = "_auth"
POLICY_TOPIC = "_policy"
ZONES_TOPIC = "_zones"
PARTS = ("instance", "lease", "commands", "watch")
#: How often the sync looks whether the bus came back (then it reads everything back).
HEALTH_CHECK_S = 0.5
#: How long :meth:`ReplicaSync.stop` waits for its work to end.
STOP_WAIT_S = 5.0


class ReplicaSync:
    def __init__(
        self,
        bus: Bus,
        instances: InstanceService,
        control: ControlService,
        commands: CommandService,
        safety: SafetyService,
        auth: AuthService,
        messages: MessageBus,
        dead_letters: DeadLetters,
    ) -> None:
        self.bus = bus
        self.messages = messages
        self.instances = instances
        self.control = control
        self.commands = commands
        self.safety = safety
        self.auth = auth
        self.dead_letters = dead_letters
        self.origin = secrets.token_hex(8)
        self._pending: dict[str, set[str]] = {}
        self._wake = asyncio.Event()
        self._tasks: set[asyncio.Task[Any]] = set()
        self._worker: asyncio.Task[None] | None = None
        self._subs: list[Subscription] = []
        self._stopped = False

    async def start(self) -> None:
        self._subs = [
            await self.bus.subscribe(STATE_TOPIC, self._on_state),
            await self.bus.subscribe(AUTH_TOPIC, self._on_auth),
            await self.bus.subscribe(POLICY_TOPIC, self._on_policy),
            await self.bus.subscribe(ZONES_TOPIC, self._on_zones),
        ]
        self._worker = asyncio.create_task(self._run(), name="replica-sync")

    async def stop(self) -> None:
        """Unsubscribe and end the work. The loop is told by ``_stopped`` as well as
        cancelled: Python 3.11's ``wait_for`` loses a cancellation that comes as the event
        it waits on is set (an announcement at shutdown), and the loop then went on for
        ever, holding the server's shutdown up. A task still running after
        :data:`STOP_WAIT_S` is logged and left."""
        self._stopped = True
        self._wake.set()
        for sub in self._subs:
            await self.bus.unsubscribe(sub)
        tasks = [task for task in (self._worker, *self._tasks) if task is not None]
        for task in tasks:
            task.cancel()
        if tasks:
            _, late = await asyncio.wait(tasks, timeout=STOP_WAIT_S)
            for task in late:
                log.error("replica sync: %s did not stop in time", task.get_name())

    # ---- what this replica wrote -------------------------------------------------
    def on_state_written(self, event: StateWritten) -> None:
        self._send(STATE_TOPIC, {"instance_id": event.instance_id, "part": event.part})

    def on_tokens_revoked(self, event: TokensRevoked) -> None:
        if event.local and (event.digests or event.token_ids):
            body = {
                "digests": sorted(event.digests),
                "token_ids": sorted(event.token_ids),
                "revoked": event.revoked,
            }
            self._send(AUTH_TOPIC, body)

    def on_failsafe_changed(self, event: FailsafeChanged) -> None:
        self._send(POLICY_TOPIC, {"vehicle_id": event.vehicle_id})

    def on_zones_changed(self, event: ZonesChanged) -> None:
        self._send(ZONES_TOPIC, {"version": event.version})

    def _send(self, topic: str, body: dict[str, Any]) -> None:
        if self._stopped:
            return
        task = asyncio.ensure_future(self.bus.publish(topic, {"origin": self.origin, **body}))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    # ---- what the others wrote ---------------------------------------------------
    def _on_state(self, _topic: str, message: Message) -> None:
        if not isinstance(message, dict) or message.get("origin") == self.origin:
            return
        instance_id, part = message.get("instance_id"), message.get("part")
        if isinstance(instance_id, str) and part in PARTS:
            self._pending.setdefault(instance_id, set()).add(str(part))
            self._wake.set()

    def _on_auth(self, _topic: str, message: Message) -> None:
        if not isinstance(message, dict) or message.get("origin") == self.origin:
            return
        digests = _strings(message.get("digests"))
        token_ids = _strings(message.get("token_ids"))
        self.auth.forget(digests, token_ids)
        revoked = message.get("revoked") is not False  # an older replica's: revoked
        self.messages.emit_now(TokensRevoked(token_ids, digests, local=False, revoked=revoked))

    def _on_policy(self, _topic: str, message: Message) -> None:
        """A vehicle's failsafe policy changed on another replica: read it again, and the
        vehicle's open long polls here look again (it is theirs to hand out at once)."""
        if not isinstance(message, dict) or message.get("origin") == self.origin:
            return
        vehicle_id = message.get("vehicle_id")
        if not isinstance(vehicle_id, str):
            return
        state = self.instances.current(vehicle_id)
        instance_id = state.instance_id if state is not None else None
        self._spawn(self._policy_again(vehicle_id, instance_id))

    async def _policy_again(self, vehicle_id: str, instance_id: str | None) -> None:
        """The policy read again; the vehicle judged again by it (a vehicle this replica
        keeps no copy of too: the store has its instance), and its open polls here told."""
        try:
            await self.safety.policy(vehicle_id)
            await self.safety.judge_again()
        except Exception as exc:  # the store away: the safety tick reads it later
            await self.dead_letters.set_aside(
                "replicas", instance_id or vehicle_id, exc, ["policy"]
            )
        if instance_id is not None:
            self.commands.wake(instance_id)

    def _on_zones(self, _topic: str, message: Message) -> None:
        """The zones changed on another replica: read them, judge the vehicles again."""
        if not isinstance(message, dict) or message.get("origin") == self.origin:
            return
        self._spawn(self._zones_again())

    async def _zones_again(self) -> None:
        try:
            await self.safety.rules_again()
        except Exception as exc:  # the store away: the safety tick reads them later
            await self.dead_letters.set_aside("replicas", "zones", exc, ["zones"])

    def _spawn(self, work: Any) -> None:
        task = asyncio.ensure_future(work)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _run(self) -> None:
        healthy = self.bus.healthy
        while not self._stopped:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._wake.wait(), HEALTH_CHECK_S)
            if self._stopped:
                return
            self._wake.clear()
            if self.bus.healthy and not healthy:  # announcements were lost meanwhile
                self._catch_up_all()
            healthy = self.bus.healthy
            # One pass per instance, however many announcements came.
            while self._pending and not self._stopped:
                instance_id = next(iter(self._pending))
                parts = self._pending.pop(instance_id)
                try:
                    await self._refresh(instance_id, parts)
                except Exception as exc:
                    await self.dead_letters.set_aside("replicas", instance_id, exc, sorted(parts))

    def _catch_up_all(self) -> None:
        self.auth.forget_all()
        held = {s.instance_id for s in self.instances.live()}
        held.update(self.commands.lane_ids, self.control.lease_ids)
        log.info("bus back: reading %d instances back from the store", len(held))
        for instance_id in held:
            self._pending.setdefault(instance_id, set()).update(PARTS)

    async def _refresh(self, instance_id: str, parts: set[str]) -> None:
        if "instance" in parts and await self.instances.refresh(instance_id):
            self.commands.forget(instance_id)  # finished on another replica
            self.control.forget(instance_id)
            return
        if "lease" in parts:
            await self.control.refresh(instance_id)
        if "commands" in parts:
            await self.commands.refresh(instance_id)
        if "watch" in parts:
            self.safety.forget_watch(instance_id)


def _strings(value: Any) -> frozenset[str]:
    return (
        frozenset(v for v in value if isinstance(v, str))
        if isinstance(value, list)
        else frozenset()
    )
