"""The vehicle agent daemon: the I/O shell around ``Pilot``, the outbox and an adapter.

Four loops run for the agent's whole life, link or no link:

- the adapter (the simulator's physics, or the ROS bridge);
- ``_sample_loop``: a sample every ``1/rate_hz`` s into the outbox;
- ``_pilot_loop``: task reports to acks, local-control changes, link-loss
  failsafe;
- ``_link_loop``: sessions with the server, retried with backoff and jitter.

A session starts (or resumes) the instance and runs four more loops until
one fails: telemetry uplink (drains the outbox oldest first, deletes what
is durable), command downlink (long poll), feedback (acks and control
mode, honouring ``abort``) and heartbeat (server clock). A ``FatalError``
ends the agent; anything else ends the session only.
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from pydantic import ValidationError

from fleet_protocol import (
    MAX_ACKS_PER_CALL,
    MAX_ACTIVE_COMMANDS,
    ControlInfo,
    FailsafePolicy,
    FbAck,
    StartInstance,
    UpdateFbMessage,
    UpdateParam,
)
from fleet_protocol.common import format_ts, utcnow
from vehicle_client.adapters.base import Adapter
from vehicle_client.backoff import Backoff
from vehicle_client.clock import ServerClock
from vehicle_client.decisions import Effect, Execute, Halt, LinkMonitor, Pilot, next_tick
from vehicle_client.errors import (
    FatalError,
    Refused,
    RetryableError,
    field_errors_of,
    refusal_of,
)
from vehicle_client.outbox import Outbox
from vehicle_client.sim.simulator import TaskReport
from vehicle_client.together import run_together
from vehicle_client.transport.base import Transport

log = logging.getLogger(__name__)

#: A long poll that comes back empty-handed this fast is not repeated sooner.
MIN_POLL_GAP_S = 0.2
#: The server clock is re-read at least this often (heartbeat's server_time).
CLOCK_SYNC_S = 30.0
#: A round trip longer than this is not reported (the wire's bound on ``rtt_s``).
MAX_REPORTED_RTT_S = 86_400.0


@dataclass
class AgentConfig:
    vehicle_id: str
    name: str = ""
    rate_hz: float = 1.0
    batch_size: int = 500
    poll_wait_s: float = 20.0
    tick_s: float = 0.2

    def __post_init__(self) -> None:
        if not 0 < self.rate_hz <= 100:
            raise FatalError(f"rate_hz must be in (0, 100], got {self.rate_hz}")
        if not 1 <= self.batch_size <= 5000:
            raise FatalError(f"batch_size must be in [1, 5000], got {self.batch_size}")
        if not 0 <= self.poll_wait_s <= 30:
            raise FatalError(f"poll_wait_s must be in [0, 30], got {self.poll_wait_s}")


@dataclass
class AgentStats:
    sessions: int = 0
    samples_sent: int = 0
    duplicates: int = 0
    durable_through_seq: int = 0
    last_error: str | None = None
    connected: bool = False
    extra: dict[str, Any] = field(default_factory=dict)


class VehicleAgent:
    def __init__(
        self,
        config: AgentConfig,
        adapter: Adapter,
        transport: Transport,
        outbox: Outbox,
        *,
        backoff: Backoff | None = None,
    ) -> None:
        self.config = config
        self.adapter = adapter
        self.transport = transport
        self.outbox = outbox
        self.backoff = backoff or Backoff()
        self.clock = ServerClock()
        caps = frozenset(adapter.capabilities) | {"stop"}
        self.pilot = Pilot(caps, seen=outbox.seen)
        self.link = LinkMonitor(after_s=self.pilot.failsafe.after_s)
        self.stats = AgentStats()
        self.instance_id: str | None = None
        #: Who holds remote control (``start_instance``'s answer, then ``control`` pushes).
        self.control: ControlInfo | None = None
        self._acks: list[FbAck] = []
        self._params: dict[str, Any] = {}
        self._sent_mode: str | None = None
        self._sent_failsafe: int | None = None
        #: The control mode and when it began (the server's clock, as estimated).
        self._mode = self.pilot.control_mode
        self._mode_since: datetime | None = None
        #: Whether the ``failsafe`` parameter says the failsafe is on (cleared on leaving).
        self._failsafe_said = False
        self._cursor = 0
        self._heartbeat_s = 1.0
        self._uplink_wake = asyncio.Event()
        self._fb_wake = asyncio.Event()

    # -- life ----------------------------------------------------------------
    async def run(self) -> None:
        """Run until cancelled; raises ``FatalError`` when retrying cannot help."""
        self._apply(self.pilot.on_restart(self.outbox.seen.unfinished()))
        await run_together(
            {
                "adapter": self.adapter.run(),
                "sample": self._sample_loop(),
                "pilot": self._pilot_loop(),
                "link": self._link_loop(),
            }
        )

    async def _link_loop(self) -> None:
        while True:
            try:
                await self._session()
            except RetryableError as exc:
                self.stats.connected = False
                self.stats.last_error = str(exc)
                delay = self.backoff.next_delay(exc.retry_after_s)
                log.warning(
                    "%s: link down (%s); retrying in %.1f s", self.config.vehicle_id, exc, delay
                )
                await asyncio.sleep(delay)

    async def _session(self) -> None:
        await self._start()
        await run_together(
            {
                "uplink": self._uplink(),
                "downlink": self._downlink(),
                "feedback": self._feedback(),
                "heartbeat": self._heartbeat(),
            }
        )

    async def _start(self) -> None:
        body = StartInstance(
            vehicle_id=self.config.vehicle_id,
            name=self.config.name or "",  # empty: the server keeps the registered name
            vehicle_type=self.adapter.vehicle_type,
            capabilities=sorted(self.pilot.capabilities),
            params=self.adapter.describe(),
            active_commands=self._active_commands(),
        )
        sent = utcnow()
        res = await self.transport.start_instance(body)
        self.clock.observe(res.server_time, sent, utcnow())
        self.instance_id = res.instance_id
        self.on_control(res.control)
        self.on_failsafe(res.failsafe)
        if res.abort:  # ended on the server while the link was down, or unknown to it
            self._apply(self.pilot.on_abort(res.abort))
        self._heartbeat_s = res.heartbeat_interval_s
        await asyncio.to_thread(self.outbox.match_server, res.last_seq)
        self._cursor = 0  # re-send from the first sample not yet durable
        self._sent_mode = None
        self._sent_failsafe = None  # said again in each session
        self.backoff.reset()
        self.stats.sessions += 1
        self.stats.connected = True
        self._contact()
        log.info(
            "%s: instance %s %s over %s, server has seq <= %d, %d samples waiting",
            self.config.vehicle_id,
            res.instance_id,
            "resumed" if res.resumed else "started",
            self.link_kind,
            res.last_seq,
            self.outbox.pending,
        )
        self._fb_wake.set()
        self._uplink_wake.set()

    def _active_commands(self) -> list[str] | None:
        """What the server is told the vehicle still has in hand: the command it carries
        out and those with an ack waiting to be sent (the server fails any other it had
        acknowledged: after a restart of this agent, nothing would ever finish it).
        None, no word, when they are more than a start may name."""
        held = [a.command_id for a in self._acks]
        if self.pilot.active_id is not None:
            held.append(self.pilot.active_id)
        distinct = list(dict.fromkeys(held))
        return distinct if len(distinct) <= MAX_ACTIVE_COMMANDS else None

    @property
    def link_kind(self) -> str:
        """``ws`` (WebSocket) or ``http`` (long poll): what the session runs on."""
        return str(getattr(self.transport, "kind", "http"))

    def on_control(self, control: ControlInfo | None) -> None:
        """Who holds remote control now (logged when it changes)."""
        if control != self.control:
            holder = control.holder if control else "nobody"
            log.info("%s: remote control held by %s", self.config.vehicle_id, holder)
        self.control = control

    def on_failsafe(self, policy: FailsafePolicy) -> None:
        """The server's policy for this vehicle: applied now, its version acknowledged."""
        if policy != self.pilot.failsafe:
            log.info(
                "%s: failsafe v%d: %s after %.0f s without the server",
                self.config.vehicle_id,
                policy.version,
                policy.action,
                policy.after_s,
            )
        self.pilot.failsafe = policy
        self.link.after_s = policy.after_s
        self._fb_wake.set()

    def _contact(self) -> None:
        if self.link.contact(asyncio.get_running_loop().time()) == "restored":
            action = self.pilot.failsafe.action
            if action == "none":
                log.warning(
                    "%s: link back (the failsafe is none: it carried on)", self.config.vehicle_id
                )
            else:
                log.warning(
                    "%s: link back; the failsafe (%s) had taken over",
                    self.config.vehicle_id,
                    action,
                )
            self._fb_wake.set()

    # -- session loops ---------------------------------------------------------
    async def _uplink(self) -> None:
        assert self.instance_id is not None
        size = self.config.batch_size
        while True:
            batch = await asyncio.to_thread(self.outbox.batch, self._cursor, size)
            params = dict(self._params)
            if batch or params:
                sent = utcnow()
                try:
                    body = UpdateParam(
                        instance_id=self.instance_id,
                        params=params,
                        samples=batch,
                        **self._timing(sent),
                    )
                except ValidationError as exc:
                    await self._refused(field_errors_of(exc), batch, exc)
                    continue
                try:
                    res = await self.transport.update_param(body)
                except Refused as exc:  # a rule the server has and this agent lacks
                    await self._refused(exc.fields, batch, exc)
                    continue
                if res.server_time is not None:
                    self.clock.observe(res.server_time, sent, utcnow())
                self._contact()
                for key, value in params.items():
                    if self._params.get(key, object()) == value:
                        del self._params[key]
                self.stats.samples_sent += res.accepted
                self.stats.duplicates += res.duplicates
                self.stats.durable_through_seq = res.durable_through_seq
                await asyncio.to_thread(self.outbox.confirm_durable, res.durable_through_seq)
                top = batch[-1]["seq"] if batch else self._cursor
                self._cursor = res.acked_through_seq
                if len(batch) == size and res.acked_through_seq >= top:
                    continue  # draining a backlog: next batch at once
            await self._wait(self._uplink_wake, 1.0 / self.config.rate_hz)

    def _timing(self, sent: datetime) -> dict[str, Any]:
        """The call's send time, and the clock offset and round trip the link has shown
        (the server's measure of the vehicle → server delay: docs/live.md)."""
        if not self.clock.synced:
            return {"sent_at": sent}
        rtt = self.clock.rtt_s
        return {
            "sent_at": sent,
            "clock_offset_s": self.clock.offset_s,
            "rtt_s": rtt if rtt is not None and rtt <= MAX_REPORTED_RTT_S else None,
        }

    async def _refused(
        self, errors: list[tuple[str, str]], batch: list[dict[str, Any]], exc: Exception
    ) -> None:
        """What the wire model or the server refuses cannot block the queue for good:
        samples stored before a rule existed leave the outbox, bad parameters are dropped.
        ``errors``: ``(field, message)``; anything else refused is raised (``exc``)."""
        refusal = refusal_of(errors, batch)
        if refusal.seqs:
            await asyncio.to_thread(self.outbox.refuse, refusal.seqs, refusal.reason)
        if refusal.params:
            log.error("%s: parameters not sent: %s", self.config.vehicle_id, refusal.reason)
            self._params.clear()
        elif not refusal.seqs:
            raise exc  # neither a sample nor a parameter: not the data's fault

    async def _downlink(self) -> None:
        assert self.instance_id is not None
        loop = asyncio.get_running_loop()
        while True:
            asked = loop.time()
            res = await self.transport.get_control(self.instance_id, self.config.poll_wait_s)
            self._contact()
            if "control" in res.model_fields_set:  # over HTTP (a socket pushes it)
                self.on_control(res.control)
            if res.failsafe is not None:
                self.on_failsafe(res.failsafe)
            if res.abort:  # ended on the server (cancelled, say): stop carrying them out
                self._apply(self.pilot.on_abort(res.abort))
            if res.commands:
                now = self.clock.server_now(utcnow())
                self._apply(self.pilot.on_commands(res.commands, now))
            # A poll that came back at once is not repeated sooner than this.
            await asyncio.sleep(max(0.0, MIN_POLL_GAP_S - (loop.time() - asked)))

    async def _feedback(self) -> None:
        assert self.instance_id is not None
        while True:
            await self._fb_wake.wait()
            self._fb_wake.clear()
            acks = self._acks[:MAX_ACKS_PER_CALL]
            mode = self.pilot.control_mode
            version = self.pilot.failsafe.version
            if not acks and mode == self._sent_mode and version == self._sent_failsafe:
                continue
            body = UpdateFbMessage(
                instance_id=self.instance_id,
                control_mode=mode,
                acks=acks,
                failsafe_version=version,
                control_mode_since=self._mode_since if mode == self._mode else None,
            )
            res = await self.transport.update_fbmessage(body)
            self._contact()
            del self._acks[: len(acks)]
            self._sent_mode = mode
            self._sent_failsafe = version
            if res.abort:
                self._apply(self.pilot.on_abort(res.abort))
            if self._acks:
                self._fb_wake.set()

    async def _heartbeat(self) -> None:
        assert self.instance_id is not None
        loop = asyncio.get_running_loop()
        synced = loop.time()
        while True:
            await asyncio.sleep(self._heartbeat_s)
            now = loop.time()
            quiet = self.link.last_contact is None or now - self.link.last_contact >= (
                self._heartbeat_s
            )
            if not quiet and now - synced < CLOCK_SYNC_S:
                continue  # other calls keep last_seen moving; the clock is fresh
            sent = utcnow()
            res = await self.transport.heartbeat(self.instance_id)
            self.clock.observe(res.server_time, sent, utcnow())
            synced = loop.time()
            self._contact()

    # -- always-on loops -------------------------------------------------------
    async def _sample_loop(self) -> None:
        loop = asyncio.get_running_loop()
        period = 1.0 / self.config.rate_hz
        due = loop.time()
        while True:
            fields = self.adapter.telemetry()
            if fields is not None and self.pilot.home is None and "lat" in fields:
                self.pilot.home = (float(fields["lat"]), float(fields["lon"]))  # return_home's
            if fields is not None:
                # The outbox checks it with the wire model: a bad reading is logged, counted
                # and left out, the good ones around it are queued.
                sample = {**fields, "ts": format_ts(utcnow())}
                if await asyncio.to_thread(self.outbox.append, sample) is not None:
                    self._uplink_wake.set()
            due = next_tick(due, loop.time(), period)
            await asyncio.sleep(max(0.0, due - loop.time()))

    async def _pilot_loop(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            await asyncio.sleep(self.config.tick_s)
            local = self.adapter.local_control
            if local != self.pilot.local_control:
                self.pilot.local_control = local
                self._note_mode()
                self._fb_wake.set()
            report = self.adapter.report()
            if report is not None:
                self._apply(self.pilot.on_report(report))
            if self.link.poll(loop.time()) == "lost":
                log.warning(
                    "%s: no answer from the server for %.0f s: failsafe %s",
                    self.config.vehicle_id,
                    self.link.after_s,
                    self.pilot.failsafe.action,
                )
                self._apply(self.pilot.on_link_lost())
                if self.pilot.in_failsafe:  # not with ``none``: the vehicle carries on
                    self._params["failsafe"] = {
                        "action": self.pilot.failsafe.action,
                        "after_s": self.link.after_s,
                        "engaged_at": format_ts(utcnow()),
                    }
                    self._failsafe_said = True

    # -- effects -----------------------------------------------------------------
    def _apply(self, effects: list[Effect]) -> None:
        for effect in effects:
            if isinstance(effect, FbAck):
                self._acks.append(effect)
            elif isinstance(effect, Execute):
                try:
                    self.adapter.execute(effect.kind, effect.args, effect.command_id)
                except (ValueError, KeyError) as exc:
                    failed = TaskReport(effect.kind, "failed", detail=f"vehicle refused: {exc}")
                    self._acks.extend(
                        e for e in self.pilot.on_report(failed) if isinstance(e, FbAck)
                    )
            elif isinstance(effect, Halt):
                self.adapter.halt()
        if self._failsafe_said and not self.pilot.in_failsafe:  # left it: said so
            self._params["failsafe"] = None
            self._failsafe_said = False
        self._note_mode()
        if effects:
            self._fb_wake.set()

    def _note_mode(self) -> None:
        """When the control mode changed, to date it in the feedback (one said after the
        link came back began when the vehicle took it, not when it could say so)."""
        mode = self.pilot.control_mode
        if mode != self._mode:
            self._mode, self._mode_since = mode, self.clock.server_now(utcnow())

    @staticmethod
    async def _wait(event: asyncio.Event, within_s: float) -> None:
        # asyncio.timeout, not wait_for: on 3.11 wait_for can swallow a cancellation
        # that arrives as the event is set, and the loop then never stops.
        try:
            async with asyncio.timeout(within_s):
                await event.wait()
        except TimeoutError:
            pass
        event.clear()
