"""Builds agents from settings and runs them until a signal (or a fatal error)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
from pathlib import Path

from vehicle_client.adapters.base import Adapter
from vehicle_client.adapters.sim import SimAdapter
from vehicle_client.agent import AgentConfig, VehicleAgent
from vehicle_client.config import LinkOptions, VehicleOptions
from vehicle_client.errors import FatalError
from vehicle_client.outbox import Outbox
from vehicle_client.sim.dynamics import VehicleParams
from vehicle_client.transport.http import HttpTransport

log = logging.getLogger("fleet-agent")

#: Seconds between status lines in the log.
STATUS_EVERY_S = 60.0


def build_adapter(options: VehicleOptions, time_scale: float) -> Adapter:
    if options.adapter == "ros":
        from vehicle_client.ros.adapter import RosAdapter

        return RosAdapter(options.ros_bridge)
    return SimAdapter(
        *options.start_latlon,
        time_scale=time_scale,
        params=VehicleParams(max_speed_mps=options.max_speed_mps),
        current=options.water_current,
    )


async def run_agents(link: LinkOptions, vehicles: list[tuple[VehicleOptions, Path]]) -> int:
    """Run one agent per vehicle over one shared link; the exit code."""
    transport = HttpTransport(link.server, link.token.get_secret_value())
    agents: list[VehicleAgent] = []
    try:
        for options, outbox_path in vehicles:
            config = AgentConfig(
                vehicle_id=options.vehicle_id,
                name=options.name,
                rate_hz=link.rate_hz,
                batch_size=link.batch_size,
                poll_wait_s=link.poll_wait_s,
            )
            adapter = build_adapter(options, link.time_scale)
            outbox = Outbox(outbox_path, max_samples=link.max_samples)
            agents.append(VehicleAgent(config, adapter, transport, outbox))
        return await _run(agents)
    finally:
        for agent in agents:
            agent.outbox.close()
        await transport.aclose()


async def _run(agents: list[VehicleAgent]) -> int:
    main = asyncio.current_task()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, main.cancel)  # type: ignore[union-attr]
    status = asyncio.create_task(_status(agents))
    try:
        results = await asyncio.gather(*(a.run() for a in agents), return_exceptions=True)
    except asyncio.CancelledError:
        log.info("stopping: the outboxes keep what was not sent")
        return 0
    finally:
        status.cancel()
    code = 0
    for agent, result in zip(agents, results, strict=True):
        if isinstance(result, FatalError):
            log.error("%s: %s", agent.config.vehicle_id, result)
            code = 2
        elif isinstance(result, BaseException):
            log.error("%s: stopped: %r", agent.config.vehicle_id, result)
            code = 1
    return code


async def _status(agents: list[VehicleAgent]) -> None:
    while True:
        await asyncio.sleep(STATUS_EVERY_S)
        for a in agents:
            log.info(
                "%s: %s, mode %s, outbox %d waiting (%d dropped), %d sent",
                a.config.vehicle_id,
                "connected" if a.stats.connected else "link down",
                a.pilot.control_mode,
                a.outbox.pending,
                a.outbox.dropped,
                a.stats.samples_sent,
            )
