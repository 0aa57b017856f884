"""``fleetctl``: the operator's and field manager's command line."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
from typing import Any

import httpx
import typer
import websockets
from rich.console import Console
from rich.table import Table

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="Operate a fleet-cloud fleet: list vehicles, send missions, manage control.",
)
console = Console()
errors = Console(stderr=True)  # stdout stays the answer alone (what --json scripts read)

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


@app.command()
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


@app.command()
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
        asyncio.run(_watch(server, token, subscribe, count, seconds, as_json))


async def _watch(
    server: str,
    token: str,
    subscribe: dict[str, Any],
    count: int | None,
    seconds: float | None,
    as_json: bool,
) -> None:
    url = server.replace("https://", "wss://", 1).replace("http://", "ws://", 1) + "/ws/client"
    try:
        ws = await websockets.connect(
            url, additional_headers={"Authorization": f"Bearer {token}"}, open_timeout=30
        )
    except (OSError, TimeoutError, websockets.InvalidHandshake) as exc:
        errors.print(f"cannot reach {server}: {exc}", style="red", markup=False)
        raise typer.Exit(3) from None
    seen = 0
    try:
        async with ws, asyncio.timeout(seconds):
            await ws.send(json.dumps(subscribe))
            async for frame in ws:
                if not isinstance(frame, str):
                    continue  # media: binary frames are not printed
                push = json.loads(frame)
                if push.get("op") == "ack" and not push.get("ok"):
                    err = push.get("error") or {}
                    errors.print(
                        f"{err.get('code')}: {err.get('message')}", style="red", markup=False
                    )
                    raise typer.Exit(1)
                if push.get("op") == "lagging":
                    errors.print(f"{push.get('dropped')} events dropped (too slow)", markup=False)
                if push.get("op") != "event":
                    continue
                _print_event(push, as_json)
                seen += 1
                if count is not None and seen >= count:
                    return
    except TimeoutError:
        return  # --seconds is over
    except websockets.ConnectionClosed as exc:
        if exc.rcvd is not None and exc.rcvd.code in (4401, 4403):
            errors.print(f"refused: {exc.rcvd.reason}", style="red", markup=False)
            raise typer.Exit(1) from None
        errors.print(f"the server closed the connection: {exc}", style="red", markup=False)
        raise typer.Exit(3) from None


def _print_event(push: dict[str, Any], as_json: bool) -> None:
    if as_json:
        print(json.dumps(push), flush=True)
        return
    head = f"{push.get('ts') or '-'} {push['topic']}" + (
        " (current)" if push.get("snapshot") else ""
    )
    data = push.get("data")
    if push["topic"] == "fleet" and isinstance(data, dict):  # a line per vehicle
        for v in data.get("vehicles", []):
            pos = v.get("position") or {}
            where = f"{pos['lat']:.5f},{pos['lon']:.5f}" if "lat" in pos else "-"
            holder = (v.get("control") or {}).get("holder", "-")
            print(f"{head} {v['vehicle_id']} {v['presence']} {where} control={holder}", flush=True)
        return
    print(f"{head} {json.dumps(data, separators=(',', ':'))}", flush=True)


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
