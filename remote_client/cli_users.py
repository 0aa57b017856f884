"""``fleetctl users`` (admin): the users, and the commands that add and change them,
disable them, and issue and revoke their tokens (a new token is printed as
:func:`~remote_client.cli_common.new_token` says)."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any, get_args

import typer
from rich.table import Table

from fleet_protocol.admin import CreateUser, Role
from remote_client.cli_common import (
    HELP_MARKUP,
    GroupTokenOpt,
    JsonOpt,
    ServerOpt,
    TokenOpt,
    dump,
    fail,
    handled,
    list_when_bare,
    new_token,
    run,
    say,
    sent_as,
)
from remote_client.output import answer_line, console, errors
from remote_client.sdk import FleetClient
from remote_client.times import plain_time

users_app = typer.Typer(
    rich_markup_mode=HELP_MARKUP,
    invoke_without_command=True,
    help="(admin) Users: list (no subcommand), add, change, disable, tokens.",
)

UsernameArg = typer.Argument(
    ..., callback=sent_as(CreateUser, "username"), help="a-z, 0-9, - and _ (ana, fm-north)"
)
VehicleOpt = typer.Option(
    None, "--vehicle", "-v", help="a vehicle (id or name) it may see; repeat for several"
)
ROLES: tuple[str, ...] = get_args(Role)


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
            plain_time(u.get("created_at")),
        )
    console.print(table)


@users_app.command("add")
def users_add(
    username: str = UsernameArg,
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
    new_token(data, as_json, f"user {username} ({role}; {seen}) created", "FLEET_TOKEN")


@users_app.command("set")
def users_set(
    username: str = UsernameArg,
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
    username: str = UsernameArg,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Disable a user: its tokens are refused and its sessions and leases end."""
    _user_said(run(server, token, lambda f: f.update_user(username, disabled=True)), as_json)


@users_app.command("enable")
def users_enable(
    username: str = UsernameArg,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Enable a disabled user (its API token works again; its sessions do not)."""
    _user_said(run(server, token, lambda f: f.update_user(username, disabled=False)), as_json)


@users_app.command("token")
def users_token(
    username: str = UsernameArg,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Issue a new API token for a user (printed once); every former token is revoked."""
    data = run(server, token, lambda fleet: fleet.rotate_token("user", username))
    what = f"new token for user {username}; every former one is revoked"
    new_token(data, as_json, what, "FLEET_TOKEN")


@users_app.command("revoke")
def users_revoke(
    username: str = UsernameArg,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Revoke every token of a user (API token and sessions; open links close)."""
    data = run(server, token, lambda fleet: fleet.revoke_tokens("user", username))
    say(data, as_json, f"every token of user {username} revoked")


# ---- helpers ------------------------------------------------------------------------
def _user_said(data: dict[str, Any], as_json: bool) -> None:
    state = "disabled" if data["disabled"] else "active"
    seen = ", ".join(data["vehicles"]) or "no vehicles"
    say(data, as_json, f"{data['username']}: {data['role']}, {state}, {seen}")


def _check_role(role: str) -> None:
    if role not in ROLES:
        fail(f"--role is one of {', '.join(ROLES)}, not {role!r}")


# ---- a person's own session -----------------------------------------------------------
def login(
    username: str = typer.Argument(..., help="your username"),
    password_stdin: bool = typer.Option(
        False, "--password-stdin", help="read the password from stdin's first line (scripts)"
    ),
    server: str = ServerOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Log in with your password: prints a session token (give it as FLEET_TOKEN).

    The password is asked on stderr, so export FLEET_TOKEN=$(fleetctl login ana) keeps
    the token alone. It lasts as long as the server's sessions do (12 h unless set
    otherwise); fleetctl logout ends it.
    """
    if password_stdin:
        password = sys.stdin.readline().rstrip("\r\n")
    else:
        password = typer.prompt("password", hide_input=True, err=True)
    if not password:
        fail("no password given")

    async def session() -> dict[str, Any]:
        async with await FleetClient.login(server, username, password) as fleet:
            token, expires_in = fleet.token, fleet.expires_in
        return {"access_token": token, "token_type": "bearer", "expires_in": expires_in}

    data = handled(server, session)
    if as_json:
        dump(data)
        return
    hours = f"{data['expires_in'] / 3600:g} h" if data["expires_in"] else "a while"
    errors.print(
        f"logged in as {username} for {hours}. Your session token (give it as FLEET_TOKEN):",
        markup=False,
        highlight=False,
    )
    answer_line(data["access_token"])


def logout(server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt) -> None:
    """End the session of FLEET_TOKEN (one from fleetctl login): it stops working at once.

    An API token (from users add or users token) is left valid: users revoke ends those.
    """
    ended = run(server, token, lambda fleet: fleet.logout())
    said = (
        "session ended: the token no longer works"
        if ended
        else "an API token, not a session: it stays valid (fleetctl users revoke ends it)"
    )
    say({"ended": ended}, as_json, said)


def _ask_password() -> str:
    """A new password, typed twice. The prompts go to stderr: stdout holds the answer
    alone (``T=$(fleetctl users add ben --ask-password)`` keeps the token)."""
    password: str = typer.prompt("password", hide_input=True, confirmation_prompt=True, err=True)
    return password


async def _vehicle_ids(fleet: FleetClient, refs: Sequence[str]) -> list[str]:
    if not refs:
        return []
    return [v["vehicle_id"] for v in await fleet.resolve_vehicles(refs)]
