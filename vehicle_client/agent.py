"""The vehicle agent daemon: the I/O shell around the outbox, an adapter and the link.

Four loops run for the agent's whole life, link or no link:

- the adapter (the simulator's physics, or the ROS bridge);
- ``_sample_loop``: a sample every ``1/rate_hz`` s into the outbox;
- the helm's (``vehicle_client.agent_commands``): task reports to acks,
  local-control changes, link-loss failsafe;
- ``_link_loop``: sessions with the server, retried with backoff and jitter.

A session starts (or resumes) the instance and runs four more loops until
one fails: telemetry uplink (drains the outbox oldest first, deletes what
is durable), command downlink (long poll) and feedback (acks and control
mode, honouring ``abort``), both the helm's, and heartbeat (server clock).
A ``FatalError`` ends the agent; anything else ends the session only.
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from pydantic import ValidationError

from fleet_protocol import StartInstance, UpdateParam
from fleet_protocol.common import format_ts, utcnow
from vehicle_client.adapters.base import Adapter
from vehicle_client.agent_commands import Helm
from vehicle_client.backoff import Backoff
from vehicle_client.clock import ServerClock
from vehicle_client.decisions import next_tick
from vehicle_client.errors import (
    FatalError,
    Refused,
    RetryableError,
    field_errors_of,
    refusal_of,
)
from vehicle_client.outbox import Outbox
from vehicle_client.together import run_together
from vehicle_client.transport.base import Transport

log = logging.getLogger(__name__)

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
        #: The commands: the pilot, the link monitor, the acks and mode owed the server.
        self.helm = Helm(config.vehicle_id, adapter, transport, self.clock, outbox.seen)
        self.stats = AgentStats()
        self.instance_id: str | None = None
        self._cursor = 0
        self._heartbeat_s = 1.0
        self._uplink_wake = asyncio.Event()

    # -- life ----------------------------------------------------------------
    async def run(self) -> None:
        """Run until cancelled; raises ``FatalError`` when retrying cannot help."""
        helm = self.helm
        helm.apply(helm.pilot.on_restart(self.outbox.seen.unfinished()))
        await run_together(
            {
                "adapter": self.adapter.run(),
                "sample": self._sample_loop(),
                "pilot": helm.run(self.config.tick_s),
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
        assert self.instance_id is not None
        await run_together(
            {
                "uplink": self._uplink(),
                "downlink": self.helm.downlink(self.instance_id, self.config.poll_wait_s),
                "feedback": self.helm.feedback(self.instance_id),
                "heartbeat": self._heartbeat(),
            }
        )

    async def _start(self) -> None:
        helm = self.helm
        body = StartInstance(
            vehicle_id=self.config.vehicle_id,
            name=self.config.name or "",  # empty: the server keeps the registered name
            vehicle_type=self.adapter.vehicle_type,  # None: the server keeps the registered one
            capabilities=sorted(helm.pilot.capabilities),
            params=self.adapter.describe(),
            active_commands=helm.active_commands(),
        )
        sent = utcnow()
        res = await self.transport.start_instance(body)
        self.clock.observe(res.server_time, sent, utcnow())
        self.instance_id = res.instance_id
        helm.on_control(res.control)
        helm.on_failsafe(res.failsafe)
        if res.abort:  # ended on the server while the link was down, or unknown to it
            helm.apply(helm.pilot.on_abort(res.abort))
        self._heartbeat_s = res.heartbeat_interval_s
        await asyncio.to_thread(self.outbox.match_server, res.last_seq)
        self._cursor = 0  # re-send from the first sample not yet durable
        self.backoff.reset()
        self.stats.sessions += 1
        self.stats.connected = True
        helm.contact()
        log.info(
            "%s: instance %s %s over %s, server has seq <= %d, %d samples waiting",
            self.config.vehicle_id,
            res.instance_id,
            "resumed" if res.resumed else "started",
            self.link_kind,
            res.last_seq,
            self.outbox.pending,
        )
        helm.resume()  # the mode and failsafe version are said again in each session
        self._uplink_wake.set()

    @property
    def link_kind(self) -> str:
        """``ws`` (WebSocket) or ``http`` (long poll): what the session runs on."""
        return str(getattr(self.transport, "kind", "http"))

    # -- session loops ---------------------------------------------------------
    async def _uplink(self) -> None:
        assert self.instance_id is not None
        size = self.config.batch_size
        owed = self.helm.params
        while True:
            batch = await asyncio.to_thread(self.outbox.batch, self._cursor, size)
            params = dict(owed)
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
                self.helm.contact()
                for key, value in params.items():
                    if owed.get(key, object()) == value:
                        del owed[key]
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
            self.helm.params.clear()
        elif not refusal.seqs:
            raise exc  # neither a sample nor a parameter: not the data's fault

    async def _heartbeat(self) -> None:
        assert self.instance_id is not None
        loop = asyncio.get_running_loop()
        link = self.helm.link
        synced = loop.time()
        while True:
            await asyncio.sleep(self._heartbeat_s)
            now = loop.time()
            quiet = link.last_contact is None or now - link.last_contact >= self._heartbeat_s
            if not quiet and now - synced < CLOCK_SYNC_S:
                continue  # other calls keep last_seen moving; the clock is fresh
            sent = utcnow()
            res = await self.transport.heartbeat(self.instance_id)
            self.clock.observe(res.server_time, sent, utcnow())
            synced = loop.time()
            self.helm.contact()

    # -- always-on loops -------------------------------------------------------
    async def _sample_loop(self) -> None:
        loop = asyncio.get_running_loop()
        period = 1.0 / self.config.rate_hz
        pilot = self.helm.pilot
        due = loop.time()
        while True:
            fields = self.adapter.telemetry()
            if fields is not None and pilot.home is None and "lat" in fields:
                pilot.home = (float(fields["lat"]), float(fields["lon"]))  # return_home's
            if fields is not None:
                # The outbox checks it with the wire model: a bad reading is logged, counted
                # and left out, the good ones around it are queued.
                sample = {**fields, "ts": format_ts(utcnow())}
                if await asyncio.to_thread(self.outbox.append, sample) is not None:
                    self._uplink_wake.set()
            due = next_tick(due, loop.time(), period)
            await asyncio.sleep(max(0.0, due - loop.time()))

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
