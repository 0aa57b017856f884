"""``fleetctl vehicles``, ``users`` and ``gateways``: the fleet's list, and the admin's
commands that register vehicles, gateways and users and issue and revoke their tokens.

A new token is printed alone on stdout (``T=$(fleetctl vehicles add usv-4)`` keeps
it) with what it is on stderr; it is shown this once. ``--json`` prints the whole
answer instead.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import typer
from rich.table import Table

from remote_client.cli_common import (
    GroupTokenOpt,
    JsonOpt,
    ServerOpt,
    TokenOpt,
    dump,
    fail,
    list_when_bare,
    run,
    say,
)
from remote_client.lines import alarms_text, position_text
from remote_client.output import answer_line, console, errors
from remote_client.sdk import FleetClient

vehicles_app = typer.Typer(
    invoke_without_command=True,
    help="The vehicles you can see (no subcommand: the list); "
    "register a vehicle, change its name or type, issue or revoke its token (admin).",
)
users_app = typer.Typer(
    invoke_without_command=True,
    help="(admin) Users: list (no subcommand), add, change, disable, tokens.",
)
gateways_app = typer.Typer(
    invoke_without_command=True,
    help="(admin) Gateways (one uplink for several vehicles): list (no subcommand), add, "
    "issue or revoke a token.",
)

VehicleOpt = typer.Option(
    None, "--vehicle", "-v", help="a vehicle (id or name) it may see; repeat for several"
)
ROLES = ("viewer", "operator", "manager", "admin")


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
    vehicle_id: str = typer.Argument(..., help="its id: a-z, 0-9, - and _ (usv-4)"),
    name: str = typer.Option("", help="display name (default: the id)"),
    vehicle_type: str = typer.Option("usv", "--type", help="usv, auv, rov, uav, ..."),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Register a vehicle; prints its token (shown once) for its agent."""
    data = run(server, token, lambda fleet: fleet.create_vehicle(vehicle_id, name, vehicle_type))
    _new_token(data, as_json, f"vehicle {vehicle_id} registered", "FLEET_AGENT_TOKEN")


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
    _new_token(data, as_json, what, "FLEET_AGENT_TOKEN")


@vehicles_app.command("revoke")
def vehicles_revoke(
    vehicle: str = typer.Argument(..., help="vehicle id or name"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Revoke every token of a vehicle: its agent is cut off.

    Its link is closed at once, and it stays off until `vehicles token` issues a new
    token. Its record and history stay.
    """

    async def act(fleet: FleetClient) -> tuple[str, dict[str, Any]]:
        vehicle_id = await fleet.vehicle_id_of(vehicle)
        return vehicle_id, await fleet.revoke_tokens("vehicle", vehicle_id)

    vehicle_id, data = run(server, token, act)
    say(data, as_json, f"every token of vehicle {vehicle_id} revoked")


# ---- gateways -----------------------------------------------------------------------
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
            (g.get("created_at") or "-")[:19].replace("T", " "),
        )
    console.print(table)


@gateways_app.command("add")
def gateways_add(
    gateway_id: str = typer.Argument(..., help="its id: a-z, 0-9, - and _"),
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
    _new_token(data, as_json, f"gateway {gateway_id} registered for {carried}", "FLEET_AGENT_TOKEN")


@gateways_app.command("token")
def gateways_token(
    gateway_id: str, server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt
) -> None:
    """Issue a new token for a gateway (printed once); its former tokens stop working."""
    data = run(server, token, lambda fleet: fleet.rotate_token("gateway", gateway_id))
    what = f"new token for gateway {gateway_id}; its former ones are revoked"
    _new_token(data, as_json, what, "FLEET_AGENT_TOKEN")


@gateways_app.command("revoke")
def gateways_revoke(
    gateway_id: str, server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt
) -> None:
    """Revoke every token of a gateway (its link is closed) until `gateways token`."""
    data = run(server, token, lambda fleet: fleet.revoke_tokens("gateway", gateway_id))
    say(data, as_json, f"every token of gateway {gateway_id} revoked")


# ---- users --------------------------------------------------------------------------
@users_app.callback()
def users(
    ctx: typer.Context,
    server: str = ServerOpt,
    token: str | None = GroupTokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    list_when_bare(ctx, server, token, as_json, _list_users)


@users_app.command("list")
def users_list(server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt) -> None:
    """Every user, with role, vehicles and whether disabled."""
    _list_users(server, token, as_json)


def _list_users(server: str, token: str, as_json: bool) -> None:
    data = run(server, token, lambda fleet: fleet.users())
    if as_json:
        dump(data)
        return
    table = Table("user", "role", "vehicles", "state", "created")
    for u in data["users"]:
        table.add_row(
            u["username"],
            u["role"],
            ", ".join(u["vehicles"]) or "-",
            "disabled" if u["disabled"] else "active",
            u.get("created_at") or "-",
        )
    console.print(table)


@users_app.command("add")
def users_add(
    username: str = typer.Argument(..., help="a-z, 0-9, - and _"),
    role: str = typer.Option("operator", help="viewer, operator, manager or admin"),
    vehicles: list[str] = VehicleOpt,
    ask_password: bool = typer.Option(
        False, "--ask-password", help="also set a password (asked here) for /auth/token logins"
    ),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Create a user; prints its API token (shown once)."""
    _check_role(role)
    password = _ask_password() if ask_password else None

    async def act(fleet: FleetClient) -> dict[str, Any]:
        ids = await _vehicle_ids(fleet, vehicles or [])
        return await fleet.create_user(username, role, ids, password=password)

    data = run(server, token, act)
    seen = ", ".join(data.get("vehicles") or []) or "no vehicles yet"
    _new_token(data, as_json, f"user {username} ({role}; {seen}) created", "FLEET_TOKEN")


@users_app.command("set")
def users_set(
    username: str,
    role: str | None = typer.Option(None, help="viewer, operator, manager or admin"),
    vehicles: list[str] = VehicleOpt,
    no_vehicles: bool = typer.Option(False, "--no-vehicles", help="take every vehicle away"),
    ask_password: bool = typer.Option(
        False, "--ask-password", help="a new password (asked here); ends the user's sessions"
    ),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Change a user's role, vehicles or password.

    The vehicles given replace the former list. A lease the new rights do not allow
    ends at once.
    """
    if role is not None:
        _check_role(role)
    if vehicles and no_vehicles:
        fail("give --vehicle or --no-vehicles, not both")
    if role is None and not vehicles and not no_vehicles and not ask_password:
        fail("nothing to change: give --role, --vehicle, --no-vehicles or --ask-password")
    password = _ask_password() if ask_password else None

    async def act(fleet: FleetClient) -> dict[str, Any]:
        ids = [] if no_vehicles else (await _vehicle_ids(fleet, vehicles) if vehicles else None)
        return await fleet.update_user(username, role=role, vehicles=ids, password=password)

    data = run(server, token, act)
    _user_said(data, as_json)


@users_app.command("disable")
def users_disable(
    username: str, server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt
) -> None:
    """Disable a user: its tokens are refused and its sessions and leases end."""
    _user_said(run(server, token, lambda f: f.update_user(username, disabled=True)), as_json)


@users_app.command("enable")
def users_enable(
    username: str, server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt
) -> None:
    """Enable a disabled user (its API token works again; its sessions do not)."""
    _user_said(run(server, token, lambda f: f.update_user(username, disabled=False)), as_json)


@users_app.command("token")
def users_token(
    username: str, server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt
) -> None:
    """Issue a new API token for a user (printed once); every former token is revoked."""
    data = run(server, token, lambda fleet: fleet.rotate_token("user", username))
    what = f"new token for user {username}; every former one is revoked"
    _new_token(data, as_json, what, "FLEET_TOKEN")


@users_app.command("revoke")
def users_revoke(
    username: str, server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt
) -> None:
    """Revoke every token of a user (API token and sessions; open links close)."""
    data = run(server, token, lambda fleet: fleet.revoke_tokens("user", username))
    say(data, as_json, f"every token of user {username} revoked")


# ---- helpers ------------------------------------------------------------------------
def _new_token(data: dict[str, Any], as_json: bool, what: str, variable: str) -> None:
    """The token alone on stdout (for ``$(...)``), what it is on stderr."""
    if as_json:
        dump(data)
        return
    errors.print(
        f"{what}. Its token, shown this once (give it as {variable}):",
        markup=False,
        highlight=False,
    )
    answer_line(data["token"])


def _user_said(data: dict[str, Any], as_json: bool) -> None:
    state = "disabled" if data["disabled"] else "active"
    seen = ", ".join(data["vehicles"]) or "no vehicles"
    say(data, as_json, f"{data['username']}: {data['role']}, {state}, {seen}")


def _check_role(role: str) -> None:
    if role not in ROLES:
        fail(f"--role is one of {', '.join(ROLES)}, not {role!r}")


def _ask_password() -> str:
    password: str = typer.prompt("password", hide_input=True, confirmation_prompt=True)
    return password


async def _vehicle_ids(fleet: FleetClient, refs: Sequence[str]) -> list[str]:
    if not refs:
        return []
    return [v["vehicle_id"] for v in await fleet.resolve_vehicles(refs)]
