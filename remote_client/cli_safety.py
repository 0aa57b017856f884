"""``fleetctl failsafe``, ``alive`` and ``audit``: what each vehicle does on its own,
keeping your leases alive, and checking a vehicle's control log."""

from __future__ import annotations

import asyncio
import contextlib
from typing import Any

import typer

from fleet_protocol import first_break
from remote_client.cli_common import (
    HELP_MARKUP,
    JsonOpt,
    ServerOpt,
    TokenOpt,
    dump,
    fail,
    finite,
    lat_lon,
    run,
    say,
)
from remote_client.output import answer_line, console, errors
from remote_client.sdk import FleetClient
from remote_client.times import plain_time

failsafe_app = typer.Typer(
    rich_markup_mode=HELP_MARKUP,
    no_args_is_help=True,
    help="A vehicle's failsafe: show it; set it (the vehicle's manager, an admin).",
)
audit_app = typer.Typer(
    rich_markup_mode=HELP_MARKUP,
    no_args_is_help=True,
    help="A vehicle's control log: show, verify.",
)

ACTIONS = ("none", "keep_station", "stop", "return_home")


# ---- failsafe ----------------------------------------------------------------------------
def _policy_text(data: dict[str, Any]) -> str:
    p = data["failsafe"]
    home = p.get("home")
    where = f" to {home['lat']:.6f},{home['lon']:.6f}" if home else ""
    state = data.get("acked")
    acked = (
        "no live instance"
        if state is None
        else ("applied by the vehicle" if state else "NOT yet applied by the vehicle")
    )
    extra = []
    if p.get("on_breach"):
        extra.append("also on a zone breach")
    if p.get("low_battery_pct") is not None:
        extra.append(f"low battery below {p['low_battery_pct']:g} %")
    more = f" ({'; '.join(extra)})" if extra else ""
    return (
        f"{data['vehicle_id']}: {p['action']}{where} after {p['after_s']:g} s without the "
        f"server{more}; version {p['version']}, {acked}"
    )


@failsafe_app.command("show")
def failsafe_show(
    vehicle: str = typer.Argument(..., help="vehicle id or name"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """What the vehicle does on its own after losing the server, and whether it applies it."""

    async def act(fleet: FleetClient) -> dict[str, Any]:
        return await fleet.failsafe(await fleet.vehicle_id_of(vehicle))

    data = run(server, token, act)
    say(data, as_json, _policy_text(data))


@failsafe_app.command("set")
def failsafe_set(
    vehicle: str = typer.Argument(..., help="vehicle id or name"),
    action: str = typer.Argument(..., help="none, keep_station, stop or return_home"),
    after: float | None = typer.Option(
        None, callback=finite, help="seconds without the server (default 30)"
    ),
    home: str | None = typer.Option(None, help="LAT,LON for return_home (default: its start)"),
    on_breach: bool = typer.Option(False, help="act also when it enters a no-go zone"),
    low_battery: float | None = typer.Option(
        None, callback=finite, help="a low_battery event below this %"
    ),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """(the vehicle's manager, admin) Set the vehicle's whole failsafe policy."""
    if action not in ACTIONS:
        fail(f"the action is one of {', '.join(ACTIONS)}, not {action!r}")
    where = None
    if home is not None:
        try:
            lat, lon = lat_lon(home)
        except ValueError:
            fail(f"--home is LAT,LON (-90 to 90, -180 to 180), not {home!r}")
        where = {"lat": lat, "lon": lon}

    async def act(fleet: FleetClient) -> dict[str, Any]:
        return await fleet.set_failsafe(
            await fleet.vehicle_id_of(vehicle),
            action=action,
            after_s=after,
            home=where,
            on_breach=on_breach,
            low_battery_pct=low_battery,
        )

    data = run(server, token, act)
    say(data, as_json, _policy_text(data))


# ---- keeping leases alive ----------------------------------------------------------------
def alive(
    seconds: float | None = typer.Option(None, min=0, callback=finite, help="stop after this long"),
    server: str = ServerOpt,
    token: str = TokenOpt,
) -> None:
    """Keep the leases you hold alive while this runs.

    A lease granted with an operator timeout lapses, and its vehicle holds station, once
    your client falls silent.
    """

    async def keep() -> None:
        async with FleetClient(server, token) as fleet, asyncio.timeout(seconds):
            await fleet.keep_leases_alive()

    errors.print("keeping your leases alive; Ctrl-C stops", highlight=False)
    with contextlib.suppress(KeyboardInterrupt, TimeoutError):
        asyncio.run(keep())


# ---- the control log ---------------------------------------------------------------------
@audit_app.command("show")
def audit_show(
    vehicle: str = typer.Argument(..., help="vehicle id or name"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """The vehicle's control log, oldest first: an entry a line (UTC, to the second)."""

    async def act(fleet: FleetClient) -> list[dict[str, Any]]:
        return await fleet.audit(await fleet.vehicle_id_of(vehicle))

    entries = run(server, token, act)
    if as_json:
        dump(entries)
        return
    if not entries:  # said on stderr: stdout holds the entries alone, for a pipe
        errors.print(f"no control log entries for {vehicle} yet", markup=False, highlight=False)
    for e in entries:
        d = e["data"]
        what = d.get("status") or d.get("holder") or d.get("action") or ""
        cmd = f" {d['type']} {d['command_id']}" if d.get("command_id") else ""
        at = plain_time(e["at"])
        answer_line(f"{e['seq']:>5} {at} {e['kind']}{cmd} {what} {e.get('actor') or ''}".rstrip())


@audit_app.command("verify")
def audit_verify(
    vehicle: str = typer.Argument(..., help="vehicle id or name"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Check the vehicle's control log: exit 0 when its hash chain holds, 1 where it breaks.

    Every entry holds the hash of the one before and matches its own.
    """

    async def act(fleet: FleetClient) -> tuple[str, list[dict[str, Any]]]:
        vehicle_id = await fleet.vehicle_id_of(vehicle)
        return vehicle_id, await fleet.audit(vehicle_id)

    vehicle_id, entries = run(server, token, act)
    broken = first_break(entries)
    result = {
        "vehicle_id": vehicle_id,
        "entries": len(entries),
        "ok": broken is None,
        "broken_at_seq": broken[0] if broken else None,
        "reason": broken[1] if broken else None,
        "last_hash": entries[-1]["hash"] if entries else None,
    }
    if as_json:
        dump(result)
    elif broken is None:
        console.print(
            f"{vehicle_id}: {len(entries)} entries, the chain holds; last hash "
            f"{result['last_hash']}",
            highlight=False,
        )
    else:
        errors.print(
            f"{vehicle_id}: the chain breaks at entry {broken[0]}: {broken[1]}",
            style="red",
            highlight=False,
        )
    if broken is not None:
        raise typer.Exit(1)
