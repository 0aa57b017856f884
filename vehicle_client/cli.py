"""``fleet-agent``: the vehicle agent (``run``) and the gateway (``gateway``).

Exit codes: 0 stopped by a signal, 2 bad configuration or refused by the
server (401/403), 1 anything else.
"""

from __future__ import annotations

import asyncio
import logging
import sys
from pathlib import Path
from typing import Annotated

import typer

from vehicle_client.config import AgentSettings, GatewaySettings, load
from vehicle_client.errors import FatalError

app = typer.Typer(
    help="fleet-agent: keeps a vehicle's link to fleet-cloud, runs its commands, "
    "and never loses its telemetry.",
    no_args_is_help=True,
    add_completion=False,
)

Opt = typer.Option


def _logging(level: str) -> None:
    logging.basicConfig(
        level=level.upper(),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    logging.getLogger("httpx").setLevel(logging.WARNING)
    logging.getLogger("httpcore").setLevel(logging.WARNING)
    logging.getLogger("websockets").setLevel(logging.WARNING)


def _fail(message: str) -> typer.Exit:
    typer.echo(f"fleet-agent: error: {message}", err=True)
    return typer.Exit(2)


@app.command()
def run(
    server: Annotated[str | None, Opt(help="server URL, e.g. http://127.0.0.1:8000")] = None,
    token: Annotated[str | None, Opt(help="vehicle token (better: FLEET_AGENT_TOKEN)")] = None,
    vehicle_id: Annotated[str | None, Opt(help="the vehicle this agent acts for")] = None,
    name: Annotated[str | None, Opt(help="display name")] = None,
    adapter: Annotated[str | None, Opt(help="sim | ros")] = None,
    start: Annotated[str | None, Opt(help="simulator start LAT,LON")] = None,
    current: Annotated[str | None, Opt(help="simulator current SPEED_MPS,TOWARDS_DEG")] = None,
    rate_hz: Annotated[float | None, Opt(help="telemetry samples per second")] = None,
    time_scale: Annotated[float | None, Opt(help="simulator runs this much faster")] = None,
    outbox: Annotated[Path | None, Opt(help="the outbox's SQLite file")] = None,
    max_samples: Annotated[int | None, Opt(help="outbox bound; past it the oldest go")] = None,
    ros_bridge: Annotated[str | None, Opt(help="ROS bridge HOST:PORT (adapter ros)")] = None,
    log_level: Annotated[str | None, Opt(help="DEBUG, INFO, WARNING")] = None,
    transport: Annotated[str | None, Opt(help="auto (WebSocket, else HTTP) | ws | http")] = None,
    retry_ws_s: Annotated[
        float | None,
        Opt(help="auto: the longest wait on HTTP before the WebSocket again (5 s first, doubling)"),
    ] = None,
    config: Annotated[Path | None, Opt(help="TOML file with the same settings")] = None,
) -> None:
    """Run the agent for one vehicle (options also from FLEET_AGENT_* or --config)."""
    from vehicle_client.runner import run_agents

    try:
        settings = load(
            AgentSettings,
            config,
            server=server,
            token=token,
            vehicle_id=vehicle_id,
            name=name,
            adapter=adapter,
            start=start,
            current=current,
            rate_hz=rate_hz,
            time_scale=time_scale,
            outbox=outbox,
            max_samples=max_samples,
            ros_bridge=ros_bridge,
            log_level=log_level,
            transport=transport,
            retry_ws_s=retry_ws_s,
        )
        if not settings.vehicle_id:
            raise FatalError("no vehicle: give --vehicle-id (or FLEET_AGENT_VEHICLE_ID)")
        _logging(settings.log_level)
        code = asyncio.run(run_agents(settings, [(settings, settings.outbox)]))
    except FatalError as exc:
        raise _fail(str(exc)) from None
    raise typer.Exit(code)


@app.command()
def gateway(
    config: Annotated[Path, Opt(help="gateway TOML file (see examples/gateway.toml)")],
    server: Annotated[str | None, Opt(help="server URL")] = None,
    token: Annotated[str | None, Opt(help="gateway token (better: FLEET_AGENT_TOKEN)")] = None,
    time_scale: Annotated[float | None, Opt(help="simulators run this much faster")] = None,
    transport: Annotated[str | None, Opt(help="auto (WebSocket, else HTTP) | ws | http")] = None,
    listen: Annotated[str | None, Opt(help="HOST:PORT of the WebSocket for local units")] = None,
) -> None:
    """Run several vehicles over one link with a gateway token."""
    from vehicle_client.runner import run_agents

    try:
        settings = load(
            GatewaySettings,
            config,
            server=server,
            token=token,
            time_scale=time_scale,
            transport=transport,
            listen=listen,
        )
        ids = [v.vehicle_id for v in settings.vehicles]
        if len(set(ids)) != len(ids):
            raise FatalError("a vehicle_id appears twice in the gateway's vehicles")
        _logging(settings.log_level)
        vehicles = [(v, settings.outbox_dir / f"{v.vehicle_id}.db") for v in settings.vehicles]
        code = asyncio.run(
            run_agents(
                settings,
                vehicles,
                batch_tick_s=settings.batch_tick_s,
                listen=settings.listen,
                unit_options={
                    "max_media_bytes": settings.max_media_bytes,
                    "media_up_per_s": settings.media_up_per_s,
                    "publish_up_per_s": settings.publish_up_per_s,
                },
            )
        )
    except FatalError as exc:
        raise _fail(str(exc)) from None
    raise typer.Exit(code)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
