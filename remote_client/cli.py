"""``fleetctl``: the operator's and field manager's command line."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import sys
from typing import Any

import httpx
import typer
from rich.table import Table

from remote_client import streams
from remote_client.output import console, errors

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="Operate a fleet-cloud fleet: list vehicles, send missions, manage control.",
)

ServerOpt = typer.Option("http://127.0.0.1:8000", envvar="FLEET_SERVER", help="server URL")
TokenOpt = typer.Option(..., envvar="FLEET_TOKEN", help="API token (FLEET_TOKEN)")
JsonOpt = typer.Option(False, "--json", help="print JSON for scripts")


def _call(server: str, token: str, method: str, path: str, **kwargs: Any) -> Any:
    with httpx.Client(
        base_url=server, headers={"Authorization": f"Bearer {token}"}, timeout=30
    ) as client:
        try:
            r = client.request(method, path, **kwargs)
        except httpx.HTTPError as exc:
            errors.print(f"cannot reach {server}: {exc}", style="red", markup=False)
            raise typer.Exit(3) from None
    if r.status_code >= 400:
        try:
            err = r.json()["error"]
            errors.print(
                f"{r.status_code} {err['code']}: {err['message']}", style="red", markup=False
            )
            for detail in err.get("details") or []:
                where = detail.get("instance_id") or detail.get("field") or ""
                errors.print(
                    f"  {where}: {detail.get('message', '')}", markup=False, highlight=False
                )
        except (ValueError, KeyError, TypeError, AttributeError):
            errors.print(f"{r.status_code}: {r.text[:500]}", style="red", markup=False)
        raise typer.Exit(1 if r.status_code < 500 else 2)
    return r.json()


@app.command()
def vehicles(server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt) -> None:
    """List the vehicles you can see, with presence, position and control."""
    data = _call(server, token, "GET", "/api/vehicles")
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


def _submit(
    server: str, token: str, instance_ids: list[str], command: dict[str, Any], ttl: int
) -> dict[str, Any]:
    body = {"instance_ids": instance_ids, "command": command, "ttl_s": ttl}
    result: dict[str, Any] = _call(server, token, "POST", "/client/submit_control", json=body)
    return result


@app.command()
def stop(
    instance_ids: list[str] = typer.Argument(None, help="instances to stop; none: every vehicle"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Stop vehicles at once (needs no lease). With no instance: every vehicle you can see."""
    command = {"type": "stop", "args": {}}
    _print_queued(_submit(server, token, instance_ids or ["*"], command, 30), as_json)


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
    args: dict[str, Any] = {"lat": lat, "lon": lon}
    if speed is not None:
        args["speed_mps"] = speed
    command = {"type": "go_to", "args": args}
    _print_queued(_submit(server, token, [instance_id], command, ttl), as_json)


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
    given = {"lat": lat, "lon": lon, "radius_m": radius}
    command = {"type": "keep_station", "args": {k: v for k, v in given.items() if v is not None}}
    _print_queued(_submit(server, token, instance_ids, command, ttl), as_json)


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
        points.append({"lat": lat, "lon": lon})
    args: dict[str, Any] = {"waypoints": points}
    if speed is not None:
        args["speed_mps"] = speed
    if plan:
        args["plan"] = True
    command = {"type": "follow_path", "args": args}
    _print_queued(_submit(server, token, [instance_id], command, ttl), as_json)


@app.command()
def commands(
    instance_id: str, server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt
) -> None:
    """The instance's recent commands and their status."""
    data = _call(server, token, "GET", "/client/get_fbmessage", params={"instance_id": instance_id})
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
    data = _call(server, token, "POST", "/client/cancel_command", json={"command_id": command_id})
    print(json.dumps(data, indent=2) if as_json else f"{data['command_id']} {data['status']}")


@app.command()
def request(
    instance_id: str, server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt
) -> None:
    """Ask the field manager for control of an instance."""
    data = _call(
        server, token, "POST", "/client/request_control", json={"instance_id": instance_id}
    )
    print(json.dumps(data, indent=2) if as_json else f"requested: {data['request_id']}")


@app.command()
def requests(
    instance_id: str | None = typer.Argument(None, help="one instance; none: all you may answer"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """(manager) The pending control requests you may answer."""
    query = {"instance_id": instance_id} if instance_id else {}
    data = _call(server, token, "GET", "/client/control_requests", params=query)
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
    data = _call(
        server,
        token,
        "POST",
        "/client/grant_control",
        json={"instance_id": instance_id, "user": user, "duration_s": duration},
    )
    print(
        json.dumps(data, indent=2)
        if as_json
        else f"{data['holder']} holds {instance_id} until {data['expires_at']}"
    )


@app.command()
def revoke(
    instance_id: str, server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt
) -> None:
    """(manager) End the lease on an instance: its holder's queued commands are cancelled."""
    data = _call(server, token, "POST", "/client/revoke_control", json={"instance_id": instance_id})
    print(json.dumps(data, indent=2) if as_json else f"control of {instance_id} revoked")


@app.command()
def release(
    instance_id: str, server: str = ServerOpt, token: str = TokenOpt, as_json: bool = JsonOpt
) -> None:
    """Give back the lease you hold on an instance."""
    data = _call(
        server, token, "POST", "/client/release_control", json={"instance_id": instance_id}
    )
    print(json.dumps(data, indent=2) if as_json else f"control of {instance_id} released")


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
    query: dict[str, Any] = {"limit": page, "after_seq": 0}
    query.update({k: v for k, v in (("from", since), ("to", until)) if v})
    path = f"/api/vehicles/{vehicle_id}/telemetry"

    def fetch(query: dict[str, Any]) -> dict[str, Any]:
        page: dict[str, Any] = _call(server, token, "GET", path, params=query)
        return page

    with contextlib.ExitStack() as stack:
        out = sys.stdout if output == "-" else stack.enter_context(open(output, "w", newline=""))
        count = streams.export_samples(fetch, query, fmt, out)
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
    subscribe: dict[str, Any] = {"op": "subscribe", "id": "watch", "topics": topics or ["fleet"]}
    if throttle_ms:
        subscribe["throttle_ms"] = throttle_ms
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(streams.watch(server, token, subscribe, count, seconds, as_json))


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
