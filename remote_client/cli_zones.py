"""``fleetctl zones`` and ``obstacles``: where vehicles may go, and what the planner keeps
clear of. A zone or an obstacle is named by its id or its name."""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Callable
from typing import Any

import typer
from rich.table import Table

from remote_client.cli_common import (
    HELP_MARKUP,
    GroupTokenOpt,
    JsonOpt,
    ServerOpt,
    TokenOpt,
    dump,
    fail,
    finite,
    list_when_bare,
    run,
    say,
    window,
)
from remote_client.output import console
from remote_client.sdk import FleetClient
from remote_client.times import plain_time

zones_app = typer.Typer(
    rich_markup_mode=HELP_MARKUP,
    invoke_without_command=True,
    help="Operating areas and no-go zones: list (no subcommand); add, edit, remove (admin).",
)
obstacles_app = typer.Typer(
    rich_markup_mode=HELP_MARKUP,
    invoke_without_command=True,
    help="Fixed obstacles the planner keeps clear of: list (no subcommand); add, remove (admin).",
)

ZoneArg = typer.Argument(..., help="the zone's id or name (fleetctl zones)")
ObstacleArg = typer.Argument(..., help="the obstacle's id or name (fleetctl obstacles)")
ClearanceOpt = typer.Option(None, callback=finite, help="metres a planned path keeps from it")


#: What a file of ``zones add``, ``zones edit --polygon`` and ``obstacles add`` may hold.
POLYGON_FILE = (
    "a GeoJSON Polygon, a Feature whose geometry is one, or a FeatureCollection of "
    "exactly one such Feature"
)


def _polygon(path: str) -> Any:
    """The GeoJSON Polygon in the file (:data:`POLYGON_FILE`); unreadable, or holding
    no Polygon or several: exit 2, before anything is sent."""
    try:
        with open(path, encoding="utf-8") as f:
            shape = json.load(f)
    except (OSError, ValueError) as exc:
        fail(f"cannot read {path}: {exc}")
    if not isinstance(shape, dict):
        fail(f"{path} holds no GeoJSON object: give {POLYGON_FILE}")
    if shape.get("type") == "FeatureCollection":
        features = shape.get("features")
        features = features if isinstance(features, list) else []
        held = [_geometry_type(f) for f in features]
        if held != ["Polygon"]:
            kinds = Counter(held)
            what = ", ".join(f"{n} {kind}" for kind, n in sorted(kinds.items()))
            fail(
                f"{path} holds a FeatureCollection of {len(held)} "
                f"feature{'' if len(held) == 1 else 's'}{f' ({what})' if what else ''}: a zone "
                f"or an obstacle is one Polygon; give {POLYGON_FILE} (one file each)"
            )
        shape = features[0]
    polygon = shape.get("geometry", shape) if shape.get("type") == "Feature" else shape
    if not isinstance(polygon, dict) or polygon.get("type") != "Polygon":
        fail(f"{path} holds a {_geometry_type(shape)}, not a Polygon: give {POLYGON_FILE}")
    return polygon


def _geometry_type(value: Any) -> str:
    """``Polygon``, ``Point``..., a Feature's geometry's (``no geometry``: a Feature
    without one; ``no GeoJSON``: not an object)."""
    if not isinstance(value, dict):
        return "no GeoJSON"
    if value.get("type") == "Feature":
        geometry = value.get("geometry")
        return str(geometry.get("type")) if isinstance(geometry, dict) else "no geometry"
    return str(value.get("type"))


# ---- zones ------------------------------------------------------------------------------
@zones_app.callback()
def zones(
    ctx: typer.Context,
    at: str | None = typer.Option(
        None, "--at", help="the zones as they were then (10m, 2h, ISO 8601), as a replay draws them"
    ),
    server: str = ServerOpt,
    token: str | None = GroupTokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    _listed_at(ctx, at, "zones", _list_zones, server, token, as_json)


def _listed_at(
    ctx: typer.Context,
    at: str | None,
    what: str,
    lister: Callable[[str, str, bool, str | None], None],
    server: str,
    token: str | None,
    as_json: bool,
) -> None:
    """A group called bare: its list, of now or (``--at``) of a past time, which goes with
    no subcommand."""
    then, _ = window(at, None)
    if at is not None and ctx.invoked_subcommand is not None:
        fail(f"--at lists the {what} of a past time: not with {ctx.invoked_subcommand}")
    list_when_bare(ctx, server, token, as_json, lambda s, t, j: lister(s, t, j, then))


def _as_at(at: str | None) -> str:
    return f", as at {plain_time(at)} UTC" if at else ""


def _list_zones(server: str, token: str, as_json: bool, at: str | None = None) -> None:
    data = run(server, token, lambda fleet: fleet.zones(at))
    if as_json:
        dump(data)
        return
    table = Table(title=f"zones (version {data['version']}{_as_at(at)})")
    for name in ("zone", "name", "kind", "vehicles", "clearance m"):
        table.add_column(name, no_wrap=name == "zone")
    for z in data["zones"]:
        vehicles = ", ".join(z["vehicles"]) or "every vehicle"
        table.add_row(z["zone_id"], z["name"], z["kind"], vehicles, f"{z['clearance_m']:g}")
    console.print(table)


def _zone_line(data: dict[str, Any]) -> str:
    return f"{data['zone_id']}: {data['kind']} {data['name']} (zones v{data['version']})"


@zones_app.command("add")
def zones_add(
    name: str = typer.Argument(..., help="what the zone is called"),
    geojson: str = typer.Argument(
        ..., help="a file holding a GeoJSON Polygon (or a Feature, or a FeatureCollection of one)"
    ),
    kind: str = typer.Option("no_go", help="no_go or operating_area"),
    vehicle: list[str] = typer.Option(
        None, "--vehicle", "-v", help="a vehicle it applies to; repeat (an area needs one)"
    ),
    clearance: float | None = ClearanceOpt,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """(admin) Draw a zone from a GeoJSON file."""
    if kind not in ("no_go", "operating_area"):
        fail(f"--kind is no_go or operating_area, not {kind!r}")
    polygon = _polygon(geojson)

    async def act(fleet: FleetClient) -> dict[str, Any]:
        ids = [await fleet.vehicle_id_of(v) for v in vehicle or []]
        return await fleet.create_zone(name, kind, polygon, ids, clearance)

    data = run(server, token, act)
    say(data, as_json, _zone_line(data))


@zones_app.command("edit")
def zones_edit(
    zone: str = ZoneArg,
    name: str | None = typer.Option(None, help="a new name"),
    polygon: str | None = typer.Option(
        None,
        help="a file with the new GeoJSON Polygon (or a Feature, or a FeatureCollection of one)",
    ),
    vehicle: list[str] = typer.Option(
        None, "--vehicle", "-v", help="the vehicles it applies to from now on; repeat"
    ),
    every_vehicle: bool = typer.Option(
        False, "--every-vehicle", help="(a no-go zone) it applies to every vehicle from now on"
    ),
    clearance: float | None = ClearanceOpt,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """(admin) Change a zone: what is given changes, the rest stays (its kind cannot)."""
    if vehicle and every_vehicle:
        fail("--vehicle and --every-vehicle cannot go together")
    changes: dict[str, Any] = {}
    if name is not None:
        changes["name"] = name
    if polygon is not None:
        changes["polygon"] = _polygon(polygon)
    if clearance is not None:
        changes["clearance_m"] = clearance
    if every_vehicle:
        changes["vehicles"] = []
    if not changes and not vehicle:
        fail("nothing to change: give --name, --polygon, --vehicle, --every-vehicle or "
             "--clearance")  # fmt: skip

    async def act(fleet: FleetClient) -> dict[str, Any]:
        zone_id = await fleet.zone_id_of(zone)
        if vehicle:
            changes["vehicles"] = [await fleet.vehicle_id_of(v) for v in vehicle]
        return await fleet.update_zone(zone_id, **changes)

    data = run(server, token, act)
    say(data, as_json, _zone_line(data))


@zones_app.command("remove")
def zones_remove(
    zone: str = ZoneArg,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """(admin) Remove a zone."""

    async def act(fleet: FleetClient) -> dict[str, Any]:
        return await fleet.delete_zone(await fleet.zone_id_of(zone))

    data = run(server, token, act)
    say(data, as_json, f"{data['zone_id']} ({data['name']}) removed")


# ---- obstacles ------------------------------------------------------------------------
@obstacles_app.callback()
def obstacles(
    ctx: typer.Context,
    at: str | None = typer.Option(
        None,
        "--at",
        help="the obstacles there were then (10m, 2h, ISO 8601), as a replay draws them",
    ),
    server: str = ServerOpt,
    token: str | None = GroupTokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    _listed_at(ctx, at, "obstacles", _list_obstacles, server, token, as_json)


def _list_obstacles(server: str, token: str, as_json: bool, at: str | None = None) -> None:
    data = run(server, token, lambda fleet: fleet.obstacles(at))
    if as_json:
        dump(data)
        return
    table = Table(title=f"fixed obstacles{_as_at(at)}")
    for name in ("obstacle", "name", "vertices", "clearance m"):
        table.add_column(name, no_wrap=name == "obstacle")
    for o in data["obstacles"]:
        ring = o["polygon"]["coordinates"][0]
        table.add_row(o["obstacle_id"], o["name"], str(len(ring) - 1), f"{o['clearance_m']:g}")
    console.print(table)


@obstacles_app.command("add")
def obstacles_add(
    name: str = typer.Argument(..., help="what the obstacle is called"),
    geojson: str = typer.Argument(
        ..., help="a file holding a GeoJSON Polygon (or a Feature, or a FeatureCollection of one)"
    ),
    clearance: float | None = ClearanceOpt,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """(admin) Draw a fixed obstacle from a GeoJSON file."""
    polygon = _polygon(geojson)
    data = run(server, token, lambda fleet: fleet.create_obstacle(name, polygon, clearance))
    say(data, as_json, f"{data['obstacle_id']}: {data['name']}")


@obstacles_app.command("remove")
def obstacles_remove(
    obstacle: str = ObstacleArg,
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """(admin) Remove a fixed obstacle."""

    async def act(fleet: FleetClient) -> dict[str, Any]:
        return await fleet.delete_obstacle(await fleet.obstacle_id_of(obstacle))

    data = run(server, token, act)
    say(data, as_json, f"{data['obstacle_id']} ({data['name']}) removed")
