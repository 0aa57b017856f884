"""``fleetctl``: the operator's and field manager's command line."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import sys
from collections.abc import Awaitable, Callable
from typing import Any, TypeVar

import httpx
import typer
from rich.table import Table

from remote_client import streams
from remote_client.output import console, errors
from remote_client.sdk import FleetApiError, FleetClient

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="Operate a fleet-cloud fleet: list vehicles, send missions, manage control.",
)

ServerOpt = typer.Option("http://127.0.0.1:8000", envvar="FLEET_SERVER", help="server URL")
TokenOpt = typer.Option(..., envvar="FLEET_TOKEN", help="API token (FLEET_TOKEN)")
JsonOpt = typer.Option(False, "--json", help="print JSON for scripts")


T = TypeVar("T")


def _run(server: str, token: str, action: Callable[[FleetClient], Awaitable[T]]) -> T:
    """``action`` on a :class:`FleetClient` session; a refusal or a network failure is
    printed on stderr and becomes the exit code (1 refused, 2 server error, 3 unreachable)."""

    async def session() -> T:
        async with FleetClient(server, token) as fleet:
            return await action(fleet)

    try:
        return asyncio.run(session())
    except httpx.HTTPError as exc:
        errors.print(f"cannot reach {server}: {exc}", style="red", markup=False)
        raise typer.Exit(3) from None
    except FleetApiError as exc:
        streams.print_refusal(exc)
        raise typer.Exit(1 if exc.status < 500 else 2) from None


@app.command()
def vehicles(server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt) -> None:
    """List the vehicles you can see, with presence, position and control."""
    data = _run(server, token, lambda fleet: fleet.vehicles())
    if as_json:
        print(json.dumps(data, indent=2))
        return
    table = Table()
    table.add_column("vehicle", no_wrap=True)
    for name in ("name", "type", "presence", "position", "control"):
        table.add_column(name)
    table.add_column("instance", no_wrap=True)  # whole: the id the other commands take
    for v in data["vehicles"]:
        pos = v.get("position")
        where = f"{pos['lat']:.5f}, {pos['lon']:.5f}" if pos else "-"
        ctl = v.get("control")
        table.add_row(
            v["vehicle_id"],
            v["name"],
            v["vehicle_type"],
            v["presence"],
            where,
            ctl["holder"] if ctl else "-",
            v.get("instance_id") or "-",
        )
    console.print(table)


InstancesArg = typer.Argument(..., help="one or more instance ids")
#: Negative coordinates (-33.9) are arguments, not unknown options.
COORDINATES = {"ignore_unknown_options": True}
TtlOpt = typer.Option(30, help="seconds the order stays valid")
SpeedOpt = typer.Option(None, help="m/s")


@app.command()
def stop(
    instance_ids: list[str] = typer.Argument(None, help="instances to stop; none: every vehicle"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Stop vehicles at once (needs no lease). With no instance: every vehicle you can see."""
    _print_queued(_run(server, token, lambda fleet: fleet.stop(instance_ids or None)), as_json)


@app.command(context_settings=COORDINATES)
def goto(
    instance_id: str,
    lat: float,
    lon: float,
    speed: float | None = SpeedOpt,
    ttl: int = TtlOpt,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Send one vehicle to a position (needs a lease)."""
    data = _run(
        server, token, lambda fleet: fleet.go_to(instance_id, lat, lon, speed_mps=speed, ttl_s=ttl)
    )
    _print_queued(data, as_json)


@app.command()
def station(
    instance_ids: list[str] = InstancesArg,
    lat: float | None = typer.Option(None, help="degrees; none: where the vehicle is"),
    lon: float | None = typer.Option(None, help="degrees; none: where the vehicle is"),
    radius: float | None = typer.Option(None, help="metres (the server's default: 2)"),
    ttl: int = TtlOpt,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Keep station: hold a position, or where each vehicle is (needs a lease on each)."""
    if (lat is None) != (lon is None):
        errors.print("give both --lat and --lon, or neither", style="red")
        raise typer.Exit(2)
    data = _run(
        server,
        token,
        lambda fleet: fleet.keep_station(
            instance_ids, lat=lat, lon=lon, radius_m=radius, ttl_s=ttl
        ),
    )
    _print_queued(data, as_json)


@app.command(context_settings=COORDINATES)
def path(
    instance_id: str,
    waypoints: list[str] = typer.Argument(..., help="LAT,LON pairs, in order"),
    speed: float | None = SpeedOpt,
    plan: bool = typer.Option(False, "--plan", help="let the server route around obstacles"),
    ttl: int = TtlOpt,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Follow a path of waypoints (needs a lease)."""
    points = []
    for text in waypoints:
        try:
            lat, lon = (float(part) for part in text.split(","))
        except ValueError:
            errors.print(f"not a LAT,LON pair: {text!r}", style="red", markup=False)
            raise typer.Exit(2) from None
        points.append((lat, lon))
    data = _run(
        server,
        token,
        lambda fleet: fleet.follow_path(instance_id, points, speed_mps=speed, plan=plan, ttl_s=ttl),
    )
    _print_queued(data, as_json)


@app.command()
def commands(
    instance_id: str, server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt
) -> None:
    """The instance's recent commands and their status."""
    data = _run(server, token, lambda fleet: fleet.commands(instance_id))
    if as_json:
        print(json.dumps(data, indent=2))
        return
    table = Table("type", "status", "issued by", "issued at", "last detail")
    table.add_column("command", no_wrap=True)  # whole: the id cancel takes
    for c in data["commands"]:
        detail = next((h.get("detail") for h in reversed(c["history"]) if h.get("detail")), None)
        table.add_row(
            c["type"], c["status"], c["issued_by"], c["issued_at"], detail or "-", c["command_id"]
        )
    console.print(f"control mode: {data['control_mode']}")
    console.print(table)


@app.command()
def cancel(
    command_id: str, server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt
) -> None:
    """Cancel a command that is not final yet."""
    data = _run(server, token, lambda fleet: fleet.cancel(command_id))
    _say(data, as_json, f"{data['command_id']} {data['status']}")


@app.command()
def request(
    instance_id: str, server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt
) -> None:
    """Ask the field manager for control of an instance."""
    data = _run(server, token, lambda fleet: fleet.request_control(instance_id))
    _say(data, as_json, f"requested: {data['request_id']}")


@app.command()
def requests(
    instance_id: str | None = typer.Argument(None, help="one instance; none: all you may answer"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """(manager) The pending control requests you may answer."""
    data = _run(server, token, lambda fleet: fleet.control_requests(instance_id))
    if as_json:
        print(json.dumps(data, indent=2))
        return
    table = Table("user", "requested at", "request")
    table.add_column("instance", no_wrap=True)  # whole: the id grant takes
    for r in data["requests"]:
        table.add_row(r["username"], r["requested_at"], r["request_id"], r["instance_id"])
    console.print(table)


@app.command()
def grant(
    instance_id: str,
    user: str,
    duration: int = typer.Option(3600, help="seconds"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """(manager) Grant remote control of an instance to an operator."""
    data = _run(server, token, lambda fleet: fleet.grant_control(instance_id, user, duration))
    _say(data, as_json, f"{data['holder']} holds {instance_id} until {data['expires_at']}")


@app.command()
def revoke(
    instance_id: str, server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt
) -> None:
    """(manager) End the lease on an instance: its holder's queued commands are cancelled."""
    data = _run(server, token, lambda fleet: fleet.revoke_control(instance_id))
    _say(data, as_json, f"control of {instance_id} revoked")


@app.command()
def release(
    instance_id: str, server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt
) -> None:
    """Give back the lease you hold on an instance."""
    data = _run(server, token, lambda fleet: fleet.release_control(instance_id))
    _say(data, as_json, f"control of {instance_id} released")


@app.command()
def export(
    vehicle_id: str,
    since: str | None = typer.Option(None, "--from", help="ISO 8601 time, inclusive"),
    until: str | None = typer.Option(None, "--to", help="ISO 8601 time, exclusive"),
    fmt: str = typer.Option("jsonl", "--format", help="jsonl (a sample per line) or csv"),
    output: str = typer.Option("-", "--output", "-o", help="file to write; -: stdout"),
    page: int = typer.Option(10_000, min=1, max=10_000, help="samples per request"),
    server: str = ServerOpt,
    token: str = TokenOpt,
) -> None:
    """Every stored telemetry sample of a vehicle, in seq order, page by page."""
    if fmt not in ("jsonl", "csv"):
        errors.print(f"--format is jsonl or csv, not {fmt!r}", style="red", markup=False)
        raise typer.Exit(2)
    with contextlib.ExitStack() as stack:
        out = sys.stdout if output == "-" else stack.enter_context(open(output, "w", newline=""))
        count = _run(
            server,
            token,
            lambda fleet: streams.export_samples(
                fleet.telemetry_pages(vehicle_id, since=since, until=until, page=page), fmt, out
            ),
        )
    if output != "-":
        errors.print(f"{count} samples written to {output}", markup=False, highlight=False)


@app.command()
def watch(
    topics: list[str] = typer.Argument(None, help="topics to follow; none: fleet"),
    count: int | None = typer.Option(None, min=1, help="stop after this many events"),
    seconds: float | None = typer.Option(None, min=0, help="stop after this long"),
    throttle_ms: int = typer.Option(0, min=0, help="at most one event per topic per N ms"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Follow topics live: each topic's current state first, then every change.

    fleet (presence), vehicle/ID/telemetry, .../commands, .../control,
    .../events, or any topic a unit publishes. Ctrl-C stops.
    """
    with contextlib.suppress(KeyboardInterrupt):
        follow = streams.Follow(topics or ["fleet"], throttle_ms, count, seconds, as_json)
        asyncio.run(streams.watch(FleetClient(server, token), follow))


def _say(data: dict[str, Any], as_json: bool, text: str) -> None:
    """The answer: its JSON for scripts, else ``text`` for people."""
    print(json.dumps(data, indent=2) if as_json else text)


def _print_queued(data: dict[str, Any], as_json: bool) -> None:
    if as_json:
        print(json.dumps(data, indent=2))
        return
    for c in data["commands"]:
        console.print(f"{c['instance_id']}: {c['command_id']} {c['status']}")


def main() -> None:
    app(prog_name=os.path.basename("fleetctl"))


if __name__ == "__main__":
    main()
