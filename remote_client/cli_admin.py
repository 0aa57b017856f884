"""``fleetctl vehicles`` and ``gateways``: the fleet's list, and the admin's commands
that register vehicles and gateways, change a vehicle, and issue and revoke their tokens
(users: :mod:`remote_client.cli_users`).

A new token is printed alone on stdout (``T=$(fleetctl vehicles add usv-4)`` keeps
it) with what it is on stderr; it is shown this once. ``--json`` prints the whole
answer instead.
"""

from __future__ import annotations

from typing import Any

import typer
from rich.table import Table

from fleet_protocol.admin import CreateGateway, CreateVehicle
from remote_client.cli_common import (
    HELP_MARKUP,
    GroupTokenOpt,
    JsonOpt,
    ServerOpt,
    TokenOpt,
    dump,
    fail,
    list_when_bare,
    new_token,
    run,
    say,
    sent_as,
)
from remote_client.lines import alarms_text, position_text
from remote_client.output import console
from remote_client.sdk import FleetClient
from remote_client.times import plain_time

vehicles_app = typer.Typer(
    rich_markup_mode=HELP_MARKUP,
    invoke_without_command=True,
    help="The vehicles you can see (no subcommand: the list); "
    "register a vehicle, change its name or type, issue or revoke its token (admin).",
)
gateways_app = typer.Typer(
    rich_markup_mode=HELP_MARKUP,
    invoke_without_command=True,
    help="(admin) Gateways (one uplink for several vehicles): list (no subcommand), add, "
    "issue or revoke a token.",
)


# ---- vehicles -----------------------------------------------------------------------
@vehicles_app.callback()
def vehicles(
    ctx: typer.Context,
    server: str = ServerOpt,
    token: str | None = GroupTokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    list_when_bare(ctx, server, token, as_json, _list_vehicles)


@vehicles_app.command("list")
def vehicles_list(server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt) -> None:
    """List the vehicles you can see, with presence, position and control."""
    _list_vehicles(server, token, as_json)


def _list_vehicles(server: str, token: str, as_json: bool) -> None:
    data = run(server, token, lambda fleet: fleet.vehicles())
    if as_json:
        dump(data)
        return
    # The numbers whole; the name wraps. Instance ids only with --json: every command
    # takes the vehicle's id or name and finds its current instance.
    table = Table()
    table.add_column("vehicle", no_wrap=True)
    table.add_column("name")
    table.add_column("type")
    table.add_column("presence", no_wrap=True)
    table.add_column("position", no_wrap=True)
    table.add_column("control")
    for v in data["vehicles"]:
        ctl = v.get("control")
        table.add_row(
            v["vehicle_id"],
            v["name"],
            v["vehicle_type"],
            v["presence"],
            position_text(v.get("position")),
            ctl["holder"] if ctl else "-",
        )
    console.print(table)
    for v in data["vehicles"]:  # what is wrong now, a line each, under the table
        if v.get("alarms"):
            said = f"ALARM {v['name']} ({v['vehicle_id']}): {alarms_text(v)}"
            console.print(said, style="bold red", soft_wrap=True)


@vehicles_app.command("add")
def vehicles_add(
    vehicle_id: str = typer.Argument(
        ..., callback=sent_as(CreateVehicle, "vehicle_id"), help="its id: a-z, 0-9, - and _ (usv-4)"
    ),
    name: str = typer.Option("", help="display name (default: the id)"),
    vehicle_type: str = typer.Option("usv", "--type", help="usv, auv, rov, uav, ..."),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Register a vehicle; prints its token (shown once) for its agent."""
    data = run(server, token, lambda fleet: fleet.create_vehicle(vehicle_id, name, vehicle_type))
    new_token(data, as_json, f"vehicle {vehicle_id} registered", "FLEET_AGENT_TOKEN")


@vehicles_app.command("set")
def vehicles_set(
    vehicle: str = typer.Argument(..., help="vehicle id or name"),
    name: str | None = typer.Option(None, help="its new display name"),
    vehicle_type: str | None = typer.Option(None, "--type", help="its type: usv, auv, rov, ..."),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Put a vehicle's name or type right (admin); its history stays.

    A name or type its agent announces when it starts still wins.
    """
    if name is None and vehicle_type is None:
        fail("nothing to change: give --name or --type")

    async def act(fleet: FleetClient) -> dict[str, Any]:
        vehicle_id = await fleet.vehicle_id_of(vehicle)
        return await fleet.update_vehicle(vehicle_id, name=name, vehicle_type=vehicle_type)

    data = run(server, token, act)
    say(data, as_json, f"vehicle {data['vehicle_id']}: {data['name']} ({data['vehicle_type']})")


@vehicles_app.command("token")
def vehicles_token(
    vehicle: str = typer.Argument(..., help="vehicle id or name"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Issue a new token for a vehicle (printed once); its former tokens stop working."""

    async def act(fleet: FleetClient) -> dict[str, Any]:
        return await fleet.rotate_token("vehicle", await fleet.vehicle_id_of(vehicle))

    data = run(server, token, act)
    what = f"new token for vehicle {data['vehicle_id']}; its former ones are revoked"
    new_token(data, as_json, what, "FLEET_AGENT_TOKEN")


@vehicles_app.command("revoke")
def vehicles_revoke(
    vehicle: str = typer.Argument(..., help="vehicle id or name"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Revoke every token of a vehicle: its agent is cut off.

    Its link is closed at once, and it stays off until a new token is issued (fleetctl
    vehicles token). Its record and history stay.
    """

    async def act(fleet: FleetClient) -> tuple[str, dict[str, Any]]:
        vehicle_id = await fleet.vehicle_id_of(vehicle)
        return vehicle_id, await fleet.revoke_tokens("vehicle", vehicle_id)

    vehicle_id, data = run(server, token, act)
    say(data, as_json, f"every token of vehicle {vehicle_id} revoked")


# ---- gateways -----------------------------------------------------------------------
GatewayArg = typer.Argument(
    ..., callback=sent_as(CreateGateway, "gateway_id"), help="its id: a-z, 0-9, - and _"
)


@gateways_app.callback()
def gateways(
    ctx: typer.Context,
    server: str = ServerOpt,
    token: str | None = GroupTokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    list_when_bare(ctx, server, token, as_json, _list_gateways)


@gateways_app.command("list")
def gateways_list(server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt) -> None:
    """Every gateway, the vehicles it carries and whether its token works."""
    _list_gateways(server, token, as_json)


def _list_gateways(server: str, token: str, as_json: bool) -> None:
    data = run(server, token, lambda fleet: fleet.gateways())
    if as_json:
        dump(data)
        return
    table = Table("gateway", "vehicles", "token", "created")
    for g in data["gateways"]:
        tokens = g.get("active_tokens", 0)
        table.add_row(
            g["gateway_id"],
            ", ".join(g["vehicles"]) or "-",
            "revoked" if not tokens else "active" if tokens == 1 else f"{tokens} active",
            plain_time(g.get("created_at")),
        )
    console.print(table)


@gateways_app.command("add")
def gateways_add(
    gateway_id: str = GatewayArg,
    vehicles: list[str] = typer.Option(..., "--vehicle", "-v", help="a vehicle it carries"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Register a gateway for some vehicles; prints its token (shown once)."""

    async def act(fleet: FleetClient) -> dict[str, Any]:
        ids = [v["vehicle_id"] for v in await fleet.resolve_vehicles(vehicles)]
        return await fleet.create_gateway(gateway_id, ids)

    data = run(server, token, act)
    carried = ", ".join(data.get("vehicles", []))
    new_token(data, as_json, f"gateway {gateway_id} registered for {carried}", "FLEET_AGENT_TOKEN")


@gateways_app.command("token")
def gateways_token(
    gateway_id: str = GatewayArg,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Issue a new token for a gateway (printed once); its former tokens stop working."""
    data = run(server, token, lambda fleet: fleet.rotate_token("gateway", gateway_id))
    what = f"new token for gateway {gateway_id}; its former ones are revoked"
    new_token(data, as_json, what, "FLEET_AGENT_TOKEN")


@gateways_app.command("revoke")
def gateways_revoke(
    gateway_id: str = GatewayArg,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Revoke every token of a gateway (its link is closed) until a new one is issued."""
    data = run(server, token, lambda fleet: fleet.revoke_tokens("gateway", gateway_id))
    say(data, as_json, f"every token of gateway {gateway_id} revoked")
