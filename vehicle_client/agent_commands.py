"""The agent's command handling: ``Pilot``'s decisions carried out, and the server told.

``Helm`` is the I/O shell around the pure ``Pilot`` and ``LinkMonitor``
(``vehicle_client.decisions``): it hands the pilot what arrives (commands
and ``abort`` lists from the server, task reports and local control from the
adapter, the link's loss and return) and carries out the effects it answers
(a task started on the adapter, a halt, an ack queued). Three loops of the
agent are the helm's:

- ``run``: every ``tick_s``, local-control changes, task reports to acks,
  the link-loss failsafe;
- ``downlink`` (one session's): commands, ``abort`` lists, control and
  failsafe changes from the server (a long poll, or a socket's pushes);
- ``feedback`` (one session's): the acks queued and the control mode (when
  it began, and the failsafe version applied) to the server, woken by
  ``wake``.

What the failsafe changes in the vehicle's parameters waits in ``params``
for the agent's telemetry uplink (``vehicle_client.agent``).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import MutableMapping
from datetime import datetime
from typing import Any

from fleet_protocol import (
    MAX_ACKS_PER_CALL,
    MAX_ACTIVE_COMMANDS,
    ControlInfo,
    FailsafePolicy,
    FbAck,
    UpdateFbMessage,
)
from fleet_protocol.common import format_ts, utcnow
from vehicle_client.adapters.base import Adapter
from vehicle_client.clock import ServerClock
from vehicle_client.decisions import Effect, Execute, Halt, LinkMonitor, Pilot
from vehicle_client.sim.simulator import TaskReport
from vehicle_client.transport.base import Transport

log = logging.getLogger(__name__)

#: A long poll that comes back empty-handed this fast is not repeated sooner.
MIN_POLL_GAP_S = 0.2


class Helm:
    """One vehicle's commands: taken from the server, carried out, acked."""

    def __init__(
        self,
        vehicle_id: str,
        adapter: Adapter,
        transport: Transport,
        clock: ServerClock,
        seen: MutableMapping[str, str],
    ) -> None:
        self.vehicle_id = vehicle_id
        self.adapter = adapter
        self.transport = transport
        self.clock = clock
        caps = frozenset(adapter.capabilities) | {"stop"}
        self.pilot = Pilot(caps, seen=seen)
        self.link = LinkMonitor(after_s=self.pilot.failsafe.after_s)
        #: Who holds remote control (``start_instance``'s answer, then ``control`` pushes).
        self.control: ControlInfo | None = None
        #: Acks not yet sent, oldest first.
        self.acks: list[FbAck] = []
        #: Parameters to send with the next telemetry (the failsafe's state).
        self.params: dict[str, Any] = {}
        #: The control mode and failsafe version the server was last told (this session).
        self.sent_mode: str | None = None
        self.sent_failsafe: int | None = None
        #: The control mode and when it began (the server's clock, as estimated).
        self.mode = self.pilot.control_mode
        self.mode_since: datetime | None = None
        #: Whether the ``failsafe`` parameter says the failsafe is on (cleared on leaving).
        self._failsafe_said = False
        #: Set when the server may have something to hear: ``feedback`` wakes.
        self.wake = asyncio.Event()

    def resume(self) -> None:
        """A session began: the mode and failsafe version are said again in it."""
        self.sent_mode = None
        self.sent_failsafe = None
        self.wake.set()

    def active_commands(self) -> list[str] | None:
        """What the server is told the vehicle still has in hand: the command it carries
        out and those with an ack waiting to be sent (the server fails any other it had
        acknowledged: after a restart of this agent, nothing would ever finish it).
        None, no word, when they are more than a start may name."""
        held = [a.command_id for a in self.acks]
        if self.pilot.active_id is not None:
            held.append(self.pilot.active_id)
        distinct = list(dict.fromkeys(held))
        return distinct if len(distinct) <= MAX_ACTIVE_COMMANDS else None

    def on_control(self, control: ControlInfo | None) -> None:
        """Who holds remote control now (logged when it changes)."""
        if control != self.control:
            holder = control.holder if control else "nobody"
            log.info("%s: remote control held by %s", self.vehicle_id, holder)
        self.control = control

    def on_failsafe(self, policy: FailsafePolicy) -> None:
        """The server's policy for this vehicle: applied now, its version acknowledged."""
        if policy != self.pilot.failsafe:
            log.info(
                "%s: failsafe v%d: %s after %.0f s without the server",
                self.vehicle_id,
                policy.version,
                policy.action,
                policy.after_s,
            )
        self.pilot.failsafe = policy
        self.link.after_s = policy.after_s
        self.wake.set()

    def contact(self) -> None:
        """The server answered: the link is alive (said when it comes back)."""
        if self.link.contact(asyncio.get_running_loop().time()) == "restored":
            action = self.pilot.failsafe.action
            if action == "none":
                log.warning("%s: link back (the failsafe is none: it carried on)", self.vehicle_id)
            else:
                log.warning(
                    "%s: link back; the failsafe (%s) had taken over", self.vehicle_id, action
                )
            self.wake.set()

    # -- loops -------------------------------------------------------------------
    async def run(self, tick_s: float) -> None:
        """The pilot's loop, link or no link: local control, task reports, link loss."""
        loop = asyncio.get_running_loop()
        while True:
            await asyncio.sleep(tick_s)
            local = self.adapter.local_control
            if local != self.pilot.local_control:
                self.pilot.local_control = local
                self._note_mode()
                self.wake.set()
            report = self.adapter.report()
            if report is not None:
                self.apply(self.pilot.on_report(report))
            if self.link.poll(loop.time()) == "lost":
                log.warning(
                    "%s: no answer from the server for %g s: failsafe %s",
                    self.vehicle_id,
                    self.link.after_s,
                    self.pilot.failsafe.action,
                )
                self.apply(self.pilot.on_link_lost())
                if self.pilot.in_failsafe:  # not with ``none``: the vehicle carries on
                    self.params["failsafe"] = {
                        "action": self.pilot.failsafe.action,
                        "after_s": self.link.after_s,
                        "engaged_at": format_ts(utcnow()),
                    }
                    self._failsafe_said = True

    async def downlink(self, instance_id: str, poll_wait_s: float) -> None:
        """Commands from the server, until the session ends."""
        loop = asyncio.get_running_loop()
        while True:
            asked = loop.time()
            res = await self.transport.get_control(instance_id, poll_wait_s)
            self.contact()
            if "control" in res.model_fields_set:  # over HTTP (a socket pushes it)
                self.on_control(res.control)
            if res.failsafe is not None:
                self.on_failsafe(res.failsafe)
            if res.abort:  # ended on the server (cancelled, say): stop carrying them out
                self.apply(self.pilot.on_abort(res.abort))
            if res.commands:
                now = self.clock.server_now(utcnow())
                self.apply(self.pilot.on_commands(res.commands, now))
            # A poll that came back at once is not repeated sooner than this.
            await asyncio.sleep(max(0.0, MIN_POLL_GAP_S - (loop.time() - asked)))

    async def feedback(self, instance_id: str) -> None:
        """Acks and the control mode to the server, until the session ends."""
        while True:
            await self.wake.wait()
            self.wake.clear()
            acks = self.acks[:MAX_ACKS_PER_CALL]
            mode = self.pilot.control_mode
            version = self.pilot.failsafe.version
            if not acks and mode == self.sent_mode and version == self.sent_failsafe:
                continue
            body = UpdateFbMessage(
                instance_id=instance_id,
                control_mode=mode,
                acks=acks,
                failsafe_version=version,
                control_mode_since=self.mode_since if mode == self.mode else None,
            )
            res = await self.transport.update_fbmessage(body)
            self.contact()
            del self.acks[: len(acks)]
            self.sent_mode = mode
            self.sent_failsafe = version
            if res.abort:
                self.apply(self.pilot.on_abort(res.abort))
            if self.acks:
                self.wake.set()

    # -- effects -----------------------------------------------------------------
    def apply(self, effects: list[Effect]) -> None:
        """Carry out what the pilot decided: acks queued, a task started, a halt."""
        for effect in effects:
            if isinstance(effect, FbAck):
                self.acks.append(effect)
            elif isinstance(effect, Execute):
                try:
                    self.adapter.execute(effect.kind, effect.args, effect.command_id)
                except (ValueError, KeyError) as exc:
                    failed = TaskReport(effect.kind, "failed", detail=f"vehicle refused: {exc}")
                    self.acks.extend(
                        e for e in self.pilot.on_report(failed) if isinstance(e, FbAck)
                    )
            elif isinstance(effect, Halt):
                self.adapter.halt()
        if self._failsafe_said and not self.pilot.in_failsafe:  # left it: said so
            self.params["failsafe"] = None
            self._failsafe_said = False
        self._note_mode()
        if effects:
            self.wake.set()

    def _note_mode(self) -> None:
        """When the control mode changed, to date it in the feedback (one said after the
        link came back began when the vehicle took it, not when it could say so)."""
        mode = self.pilot.control_mode
        if mode != self.mode:
            self.mode, self.mode_since = mode, self.clock.server_now(utcnow())
