"""``fleetctl``: the operator's and field manager's command line.

Wherever a command takes a vehicle or an instance, a vehicle's id or its display
name will do (a vehicle stands for its current instance); an instance id too.
Exit codes: ``remote_client.cli_common``.
"""

from __future__ import annotations

import os
from typing import Any

import typer
from rich import box
from rich.table import Table

from fleet_protocol.links import server_root_problem
from remote_client import cli_control, cli_data, cli_live
from remote_client.cli_admin import gateways_app, vehicles_app
from remote_client.cli_common import (
    HELP_MARKUP,
    Commands,
    JsonOpt,
    ServerOpt,
    TokenOpt,
    VehicleArg,
    between,
    dump,
    fail,
    lat_lon,
    latitude,
    longitude,
    position,
    print_queued,
    run,
    say,
    split_waypoints,
    with_names,
)
from remote_client.cli_safety import alive, audit_app, failsafe_app
from remote_client.cli_users import login, logout, users_app
from remote_client.cli_zones import obstacles_app, zones_app
from remote_client.output import console
from remote_client.sdk import STOP_TTL_S, FleetApiError, FleetClient, shown_status
from remote_client.times import short_time

app = typer.Typer(
    rich_markup_mode=HELP_MARKUP,
    cls=Commands,
    add_completion=False,
    no_args_is_help=True,
    help="Operate a fleet-cloud fleet: list vehicles, send missions, manage control, "
    "export and copy telemetry, administer users and vehicles. A vehicle's name works "
    "wherever its id does.",
)


@app.callback()
def _everywhere(
    server: str | None = typer.Option(
        None, "--server", help="server URL, for the command that follows (as FLEET_SERVER)"
    ),
    token: str | None = typer.Option(
        None, "--token", help="API token, for the command that follows (as FLEET_TOKEN)"
    ),
) -> None:
    """``fleetctl --server URL --token T vehicles``: given before the command, they stand
    for FLEET_SERVER and FLEET_TOKEN (a command's own --server, --token still win)."""
    if server is not None:
        if (problem := server_root_problem(server)) is not None:
            fail(f"--server is {problem}")
        os.environ["FLEET_SERVER"] = server
    if token is not None:
        os.environ["FLEET_TOKEN"] = token


app.add_typer(vehicles_app, name="vehicles")
app.add_typer(users_app, name="users")
app.add_typer(gateways_app, name="gateways")
app.add_typer(zones_app, name="zones")
app.add_typer(obstacles_app, name="obstacles")
app.add_typer(failsafe_app, name="failsafe")
app.add_typer(audit_app, name="audit")
app.command()(alive)
app.command()(login)
app.command()(logout)
app.command()(cli_live.watch)
app.command()(cli_live.publish)
for command in (cli_data.params, cli_data.events, cli_data.export, cli_data.track, cli_data.sync):
    app.command()(command)

VehiclesArg = typer.Argument(..., help="vehicle ids or names, or instance ids")
#: Negative coordinates (-33.9) are arguments, not unknown options.
COORDINATES = {"ignore_unknown_options": True}
TtlOpt = typer.Option(30, callback=between(1, 3600), help="seconds the order stays valid (1-3600)")
SpeedOpt = typer.Option(None, callback=between(0, 50, above=True), help="m/s (above 0, at most 50)")


async def _instances_of(fleet: FleetClient, vehicles: list[str], nothing_sent: str) -> list[str]:
    """The instances a mission's vehicles name. One name that fits no vehicle (or several)
    sends the mission to none: the refusal says so, not only which name it was (``stop
    alpha typo`` stopped nothing, and said only that ``typo`` fits no vehicle)."""
    try:
        return await fleet.instance_ids_of(vehicles)
    except FleetApiError as exc:
        exc.message += f"; {nothing_sent}"
        raise


@app.command()
def stop(
    vehicles: list[str] = typer.Argument(None, help="vehicles to stop; none: every vehicle"),
    ttl: int = typer.Option(
        STOP_TTL_S,
        callback=between(1, 3600),
        help="seconds the stop waits for a vehicle out of reach (1-3600)",
    ),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Stop vehicles at once (needs no lease); none named: every vehicle you can see.

    A vehicle out of reach gets the stop when it is back, within --ttl.
    """

    async def act(fleet: FleetClient) -> dict[str, Any]:
        ids = None
        if vehicles:
            ids = await _instances_of(fleet, vehicles, "nothing sent: no vehicle stopped")
        return await with_names(fleet, await fleet.stop(ids, ttl))

    print_queued(run(server, token, act), as_json)


@app.command(context_settings=COORDINATES)
def goto(
    targets: list[str] = typer.Argument(
        ..., metavar="VEHICLE... LAT LON", help="one vehicle or more, then the position"
    ),
    speed: float | None = SpeedOpt,
    ttl: int = TtlOpt,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Send vehicles to a position (needs a lease on each).

    Several sent to one point are warned of: they would meet there.
    """
    if len(targets) < 3:
        fail("give a vehicle (or more), then LAT and LON")
    *vehicles, lat_text, lon_text = targets
    lat, lon = position(lat_text, lon_text)

    async def act(fleet: FleetClient) -> dict[str, Any]:
        ids = await _instances_of(fleet, vehicles, "nothing sent to any vehicle")
        sent = await fleet.go_to(ids, lat, lon, speed_mps=speed, ttl_s=ttl)
        return await with_names(fleet, sent)

    print_queued(run(server, token, act), as_json)


@app.command()
def station(
    vehicles: list[str] = VehiclesArg,
    lat: float | None = typer.Option(
        None, callback=latitude, help="degrees; none: where the vehicle is"
    ),
    lon: float | None = typer.Option(
        None, callback=longitude, help="degrees; none: where the vehicle is"
    ),
    radius: float | None = typer.Option(
        None, callback=between(0, 10_000, above=True), help="metres (the server's default: 2)"
    ),
    ttl: int = TtlOpt,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Keep station: hold a position, or where each vehicle is (needs a lease on each)."""
    if (lat is None) != (lon is None):
        fail("give both --lat and --lon, or neither")

    async def act(fleet: FleetClient) -> dict[str, Any]:
        ids = await _instances_of(fleet, vehicles, "nothing sent to any vehicle")
        sent = await fleet.keep_station(ids, lat=lat, lon=lon, radius_m=radius, ttl_s=ttl)
        return await with_names(fleet, sent)

    print_queued(run(server, token, act), as_json)


@app.command(context_settings=COORDINATES)
def path(
    targets: list[str] = typer.Argument(
        ...,
        metavar="VEHICLE... LAT,LON...",
        help="one vehicle or more, then the waypoints as LAT,LON pairs, in order",
    ),
    speed: float | None = SpeedOpt,
    plan: bool = typer.Option(False, "--plan", help="let the server route around obstacles"),
    ttl: int = TtlOpt,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Follow a path of waypoints (needs a lease on each vehicle).

    The vehicles are the arguments before the first LAT,LON pair.
    """
    vehicles, waypoints = split_waypoints(targets)
    points = []
    for text in waypoints:
        try:
            points.append(lat_lon(text))
        except ValueError:
            fail(f"not a LAT,LON pair (-90 to 90, -180 to 180): {text!r}")

    async def act(fleet: FleetClient) -> dict[str, Any]:
        ids = await _instances_of(fleet, vehicles, "nothing sent to any vehicle")
        sent = await fleet.follow_path(ids, points, speed_mps=speed, plan=plan, ttl_s=ttl)
        return await with_names(fleet, sent)

    print_queued(run(server, token, act), as_json)


@app.command()
def commands(
    vehicle: str = VehicleArg,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """The recent commands of a vehicle and their status.

    A command a stop cancelled before it ran shows as superseded.
    """

    async def act(fleet: FleetClient) -> dict[str, Any]:
        return await fleet.commands(await fleet.instance_id_of(vehicle))

    data = run(server, token, act)
    if as_json:
        dump(data)
        return
    # 80 columns hold it: no vertical rules; the type, status, issuer, time and id whole
    # (the id is what cancel takes), the last detail (often the vehicle's words) wrapping.
    table = Table(box=box.SIMPLE_HEAD, show_edge=False, pad_edge=False, collapse_padding=True)
    for name in ("type", "status", "by", "at (UTC)", "command"):
        table.add_column(name, no_wrap=True)
    table.add_column("last detail", overflow="fold")
    for c in data["commands"]:
        table.add_row(
            c["type"],
            shown_status(c),
            c["issued_by"],
            short_time(c["issued_at"]),
            c["command_id"],
            _last_detail(c),
        )
    console.print(f"control mode: {data['control_mode']}")
    console.print(table)


def _last_detail(command: dict[str, Any]) -> str:
    """A command's latest detail. A superseded one's (``superseded_by_stop``, ``superseded_by
    go_to c-...``) says by what type of command, as the console does (``by a stop``, ``by
    go_to``): its status says superseded, and the newer command has its own row."""
    detail = next((h["detail"] for h in reversed(command["history"]) if h.get("detail")), "-")
    if shown_status(command) != "superseded":
        return str(detail)
    newer = detail.removeprefix("superseded_by").lstrip("_ ").split(" ")[0]
    return "by a stop" if newer in ("stop", "") else f"by {newer}"


@app.command()
def cancel(
    command_id: str, server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt
) -> None:
    """Cancel a command that is not final yet."""
    data = run(server, token, lambda fleet: fleet.cancel(command_id))
    status = shown_status(data)
    # A final command is answered as it is (docs/api.md): say it was not cancelled.
    late = "" if status == "cancelled" else ": final already, not cancelled"
    say(data, as_json, f"{data['command_id']} {status}{late}")


for control in (  # after the missions in the help's list, as the README lists them
    cli_control.request,
    cli_control.requests,
    cli_control.grant,
    cli_control.deny,
    cli_control.revoke,
    cli_control.release,
):
    app.command()(control)


def main() -> None:
    app(prog_name=os.path.basename("fleetctl"))


if __name__ == "__main__":
    main()
