"""Builds agents from settings and runs them until a signal (or a fatal error)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
from pathlib import Path
from typing import TYPE_CHECKING, Any

from vehicle_client.adapters.base import Adapter
from vehicle_client.adapters.sim import SimAdapter
from vehicle_client.agent import AgentConfig, VehicleAgent
from vehicle_client.config import LinkOptions, VehicleOptions
from vehicle_client.errors import FatalError, TokenRefused
from vehicle_client.outbox import Outbox
from vehicle_client.sim.dynamics import VehicleParams
from vehicle_client.transport.auto import AutoTransport, LinkChoice
from vehicle_client.transport.base import Transport
from vehicle_client.transport.http import HttpTransport
from vehicle_client.transport.ws import WsLink

if TYPE_CHECKING:
    from vehicle_client.gateway.units import UnitServer

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


def build_links(
    link: LinkOptions, vehicle_ids: list[str], *, batch_tick_s: float = 0.0
) -> tuple[list[Transport], WsLink | None, list[Transport]]:
    """Each vehicle's transport, the shared WebSocket link (if any) and what to close."""
    token = link.token.get_secret_value()
    http = HttpTransport(link.server, token) if link.transport != "ws" else None
    ws = WsLink(link.server, token, batch_tick_s=batch_tick_s) if link.transport != "http" else None
    choice = LinkChoice(retry_ws_s=link.retry_ws_s)
    per_vehicle: list[Transport] = []
    for vehicle_id in vehicle_ids:
        if ws is None:
            assert http is not None
            per_vehicle.append(http)
        elif http is None:
            per_vehicle.append(ws.vehicle(vehicle_id))
        else:
            per_vehicle.append(AutoTransport(ws.vehicle(vehicle_id), http, choice))
    closers: list[Transport] = [t for t in (http,) if t is not None]
    return per_vehicle, ws, closers


async def run_agents(
    link: LinkOptions,
    vehicles: list[tuple[VehicleOptions, Path]],
    *,
    batch_tick_s: float = 0.0,
    listen: str | None = None,
    unit_options: dict[str, Any] | None = None,
) -> int:
    """Run one agent per vehicle over one shared link; the exit code.

    With ``listen``, a gateway's WebSocket for local units too
    (``unit_options``: ``UnitServer``'s keyword arguments)."""
    ids = [options.vehicle_id for options, _ in vehicles]
    transports, ws, closers = build_links(link, ids, batch_tick_s=batch_tick_s)
    agents: list[VehicleAgent] = []
    units = None
    try:
        for (options, outbox_path), transport in zip(vehicles, transports, strict=True):
            config = AgentConfig(
                vehicle_id=options.vehicle_id,
                name=options.name,
                rate_hz=link.rate_hz,
                batch_size=link.batch_size,
                poll_wait_s=link.poll_wait_s,
            )
            adapter = build_adapter(options, link.time_scale)
            outbox = Outbox(
                outbox_path, max_samples=link.max_samples, vehicle_id=options.vehicle_id
            )
            agent = VehicleAgent(config, adapter, transport, outbox)
            if ws is not None:
                ws.vehicle(options.vehicle_id).on_control = agent.helm.on_control
            agents.append(agent)
        if listen is not None:
            if ws is None:
                raise FatalError("listen (local units) needs the WebSocket: transport auto or ws")
            from vehicle_client.gateway.units import UnitServer

            units = UnitServer(ws, listen, **(unit_options or {}))
            await units.start()
        return await _run(agents, units)
    finally:
        if units is not None:
            await units.stop()
        for agent in agents:
            agent.outbox.close()
        for transport in closers:
            await transport.aclose()
        if ws is not None:
            await ws.aclose()


#: The process that started this agent and takes it down with it (``make demo``): when it
#: is gone (killed with SIGKILL, say), the agent stops too, as on SIGTERM. An agent left
#: running held its outbox, and the next demo's agent for that boat could not start.
PARENT_ENV = "FLEET_AGENT_PARENT_PID"


async def _exit_with_parent(main: asyncio.Task[int], every_s: float = 1.0) -> None:
    parent = os.environ.get(PARENT_ENV)
    if not parent or not parent.isdigit():
        return
    pid = int(parent)
    if os.getppid() == pid:
        try:  # Linux: a descriptor that becomes readable when the process ends
            fd = os.pidfd_open(pid)
        except (AttributeError, OSError):
            fd = None
        if fd is not None:
            gone = asyncio.Event()
            loop = asyncio.get_running_loop()
            loop.add_reader(fd, gone.set)
            try:
                await gone.wait()
            finally:
                loop.remove_reader(fd)
                os.close(fd)
        else:  # elsewhere nothing tells of it: its parent looked at now and then
            while os.getppid() == pid:  # noqa: ASYNC110
                await asyncio.sleep(every_s)
    log.warning("the process that started this agent (%s) is gone: stopping", parent)
    main.cancel()


async def _run(agents: list[VehicleAgent], units: UnitServer | None = None) -> int:
    main = asyncio.current_task()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, main.cancel)  # type: ignore[union-attr]
    status = asyncio.create_task(_status(agents, units))
    orphan = asyncio.create_task(_exit_with_parent(main))  # type: ignore[arg-type]
    try:
        results = await asyncio.gather(*(a.run() for a in agents), return_exceptions=True)
    except asyncio.CancelledError:
        log.info("stopping: the outboxes keep what was not sent")
        return 0
    finally:
        status.cancel()
        orphan.cancel()
    if units is not None and any(isinstance(r, TokenRefused) for r in results):
        await units.token_refused()  # before the port goes: a restart would not help them
    code = 0
    for agent, result in zip(agents, results, strict=True):
        if isinstance(result, FatalError):
            log.error("%s: %s", agent.config.vehicle_id, result)
            code = 2
        elif isinstance(result, BaseException):
            log.error("%s: stopped: %r", agent.config.vehicle_id, result)
            code = 1
    return code


async def _status(agents: list[VehicleAgent], units: UnitServer | None) -> None:
    while True:
        await asyncio.sleep(STATUS_EVERY_S)
        for a in agents:
            log.info(
                "%s: %s, mode %s, control %s, outbox %d waiting (%d dropped, %d refused), %d sent",
                a.config.vehicle_id,
                f"connected over {a.link_kind}" if a.stats.connected else "link down",
                a.helm.pilot.control_mode,
                a.helm.control.holder if a.helm.control else "nobody",
                a.outbox.pending,
                a.outbox.dropped,
                a.outbox.refused,
                a.stats.samples_sent,
            )
        if units is not None:
            log.info("local units: %s", units.describe())
