"""``fleetctl``'s control commands: an operator asks for control of a vehicle and gives it
back; its field manager answers the requests, grants, declines and revokes
(``docs/commands.md``). Each says which vehicle, by name and id."""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from datetime import UTC, datetime, timedelta
from typing import Any

import typer
from rich.table import Table

from fleet_protocol import parse_ts
from fleet_protocol.client import DenyControl, GrantControl
from remote_client.cli_common import (
    JsonOpt,
    ServerOpt,
    TokenOpt,
    VehicleArg,
    between,
    boat,
    dump,
    run,
    say,
    sent_as,
)
from remote_client.output import console
from remote_client.sdk import FleetClient
from remote_client.times import short_time

__all__ = ["deny", "grant", "release", "request", "requests", "revoke"]

Call = Callable[[FleetClient, str], Awaitable[dict[str, Any]]]


def _on_vehicle(
    server: str, token: str, vehicle: str, call: Call
) -> tuple[dict[str, Any], dict[str, Any]]:
    """The vehicle's instance (for its name and id) and ``call``'s answer on it."""

    async def act(fleet: FleetClient) -> tuple[dict[str, Any], dict[str, Any]]:
        instance = await fleet.instance_of(vehicle)
        return instance, await call(fleet, instance["instance_id"])

    result: tuple[dict[str, Any], dict[str, Any]] = run(server, token, act)
    return result


def request(
    vehicle: str = VehicleArg,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Ask the field manager for control of a vehicle."""

    instance, data = _on_vehicle(
        server, token, vehicle, lambda fleet, iid: fleet.request_control(iid)
    )
    text = f"control of {boat(instance)} requested: {data['request_id']}"
    say(data, as_json, text)


def requests(
    vehicle: str | None = typer.Argument(None, help="one vehicle; none: all you may answer"),
    mine: bool = typer.Option(
        False, "--mine", help="your own requests not answered yet, not those you may answer"
    ),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """(manager) The pending control requests you may answer; --mine: your own."""

    async def act(fleet: FleetClient) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
        instance_id = await fleet.instance_id_of(vehicle) if vehicle else None
        data = await fleet.control_requests(instance_id, mine=mine)
        return data, await fleet.instance_vehicles(r["instance_id"] for r in data["requests"])

    data, vehicles = run(server, token, act)
    if as_json:
        dump(data)
        return
    # The request ids (which no command takes) with --json only: 80 columns hold the rest.
    table = Table("vehicle", "name", "user", "asked", "until", caption="times in UTC")
    table.add_column("instance", no_wrap=True)  # whole: grant and deny take it too
    for r in data["requests"]:
        v = vehicles[r["instance_id"]]
        table.add_row(
            v["vehicle_id"],
            v.get("name") or "-",
            r["username"],
            short_time(r["requested_at"]),
            short_time(r.get("expires_at")),  # dropped then if nobody answers
            r["instance_id"],
        )
    console.print(table)


def grant(
    vehicle: str = VehicleArg,
    user: str = typer.Argument(
        ..., callback=sent_as(GrantControl, "user"), help="the operator to hand control to"
    ),
    duration: int = typer.Option(3600, callback=between(1, 86400), help="seconds (1-86400)"),
    operator_timeout: int | None = typer.Option(
        None,
        min=2,
        max=3600,
        help="the lease lapses (the vehicle holds station) when the operator's client is "
        "silent this many seconds (fleetctl alive, watch and the console keep it alive)",
    ),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """(manager) Grant remote control of a vehicle to an operator."""

    asked = datetime.now(UTC) + timedelta(seconds=duration)

    instance, data = _on_vehicle(
        server,
        token,
        vehicle,
        lambda fleet, iid: fleet.grant_control(
            iid, user, duration, operator_timeout_s=operator_timeout
        ),
    )
    text = f"{data['holder']} holds {boat(instance)} until {data['expires_at']}"
    if parse_ts(data["expires_at"]) > asked + timedelta(seconds=5):  # the lease ran longer
        text += " (held already: a grant never shortens a lease; revoke it to end it sooner)"
    former = (instance.get("control") or {}).get("holder")
    if former and former != data["holder"]:  # taken from someone: said, as the log says it
        text += f"; {former}'s lease ended, its commands not yet acknowledged cancelled"
    say(data, as_json, text)


def deny(
    vehicle: str = VehicleArg,
    user: str = typer.Argument(
        ..., callback=sent_as(DenyControl, "user"), help="the operator whose request to decline"
    ),
    reason: str | None = typer.Option(None, help="why (the requester sees it)"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """(manager) Decline an operator's pending request for control of a vehicle."""

    instance, data = _on_vehicle(
        server, token, vehicle, lambda fleet, iid: fleet.deny_control(iid, user, reason)
    )
    say(data, as_json, f"{user}'s request for control of {boat(instance)} declined")


def revoke(
    vehicle: str = VehicleArg,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """(manager) End the lease on a vehicle: its holder's queued commands are cancelled."""

    instance, data = _on_vehicle(
        server, token, vehicle, lambda fleet, iid: fleet.revoke_control(iid)
    )
    done = f"control of {boat(instance)} revoked"
    say(data, as_json, done if data.get("revoked", True) else f"nobody held {boat(instance)}")


def release(
    vehicle: str = VehicleArg,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Give back the lease you hold on a vehicle."""

    instance, data = _on_vehicle(
        server, token, vehicle, lambda fleet, iid: fleet.release_control(iid)
    )
    say(data, as_json, f"control of {boat(instance)} released")
