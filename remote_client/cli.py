"""``fleetctl``: the operator's and field manager's command line."""

from __future__ import annotations

import json
import os
from typing import Any

import httpx
import typer
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
    table = Table("vehicle", "name", "type", "presence", "instance", "position", "control")
    for v in data["vehicles"]:
        pos = v.get("position")
        where = f"{pos['lat']:.5f}, {pos['lon']:.5f}" if pos else "-"
        ctl = v.get("control")
        table.add_row(
            v["vehicle_id"],
            v["name"],
            v["vehicle_type"],
            v["presence"],
            v.get("instance_id") or "-",
            where,
            ctl["holder"] if ctl else "-",
        )
    console.print(table)


@app.command()
def stop(
    instance_ids: list[str] = typer.Argument(None, help="instances to stop; none: every vehicle"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Stop vehicles at once (needs no lease). With no instance: every vehicle you can see."""
    data = _call(
        server,
        token,
        "POST",
        "/client/submit_control",
        json={"instance_ids": instance_ids or ["*"], "command": {"type": "stop", "args": {}}},
    )
    _print_queued(data, as_json)


@app.command()
def goto(
    instance_id: str,
    lat: float,
    lon: float,
    speed: float | None = typer.Option(None, help="m/s"),
    ttl: int = typer.Option(30, help="seconds the order stays valid"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Send one vehicle to a position (needs a lease)."""
    args: dict[str, Any] = {"lat": lat, "lon": lon}
    if speed is not None:
        args["speed_mps"] = speed
    data = _call(
        server,
        token,
        "POST",
        "/client/submit_control",
        json={
            "instance_ids": [instance_id],
            "command": {"type": "go_to", "args": args},
            "ttl_s": ttl,
        },
    )
    _print_queued(data, as_json)


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
