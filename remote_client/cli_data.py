"""``fleetctl params``, ``events``, ``export``, ``track`` and ``sync``: what the fleet
stored, read back, written out and copied for offline work."""

from __future__ import annotations

import contextlib
import json
import sys
import typing
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import typer
from rich.progress import (
    BarColumn,
    Progress,
    SpinnerColumn,
    TaskProgressColumn,
    TextColumn,
    TimeElapsedColumn,
)
from rich.table import Table

from fleet_protocol import EventKind
from fleet_protocol.common import format_ts, parse_ts
from remote_client import streams
from remote_client.cli_common import (
    JsonOpt,
    ServerOpt,
    SinceOpt,
    TokenOpt,
    UntilOpt,
    dump,
    fail,
    file_format,
    run,
    window,
)
from remote_client.lines import event_text, position_text
from remote_client.localcopy import LocalCopy, SyncResult, sync_vehicle
from remote_client.output import answer_line, console, errors
from remote_client.sdk import FleetClient
from remote_client.tracks import FORMATS, TrackJoiner, plot_png

#: The kinds ``--kind`` takes: the server's (``fleet_protocol.EventKind``).
EVENT_KINDS: tuple[str, ...] = typing.get_args(EventKind)
VehicleArg = typer.Argument(..., help="vehicle id or name")
#: The track's window when ``--since`` is not given (the server's default too).
DEFAULT_WINDOW = timedelta(hours=24)
#: Points a PNG plot asks for when ``--max-points`` is not given (downsampled keeping shape).
PNG_POINTS = 10_000


def params(
    vehicle: str = typer.Argument(..., help="vehicle id or name, or an instance id"),
    names: list[str] = typer.Argument(None, help="only these parameters"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """A vehicle's parameters (what its agent reported) and its latest position."""

    async def act(fleet: FleetClient) -> tuple[str, dict[str, Any]]:
        instance_id = await fleet.instance_id_of(vehicle)
        return instance_id, await fleet.params(instance_id, names or None)

    instance_id, data = run(server, token, act)
    if as_json:
        dump(data)
        return
    table = Table("parameter", "value")
    for key in sorted(data["params"]):
        table.add_row(key, json.dumps(data["params"][key], ensure_ascii=False))
    console.print(table)
    if missing := [n for n in dict.fromkeys(names or []) if n not in data["params"]]:
        # Asked for, and not among what the vehicle reported: said, not left out quietly.
        errors.print(
            f"not reported by {vehicle}: {', '.join(missing)}", markup=False, highlight=False
        )
    pos = data.get("position")
    where = position_text(pos) + (f" at {pos['ts']}" if pos else "")
    console.print(
        f"instance {instance_id}; updated {data.get('updated_at') or '-'}; position {where}",
        highlight=False,
    )


def events(
    vehicle: str | None = typer.Argument(None, help="vehicle id or name; none: every vehicle"),
    kind: str | None = typer.Option(None, help="only this kind (command, control_grant, ...)"),
    since: str | None = SinceOpt,
    until: str | None = UntilOpt,
    limit: int = typer.Option(1000, min=1, max=10_000, help="at most this many (a page)"),
    after: str | None = typer.Option(
        None, help="the page after this one: the cursor the page before ended with"
    ),
    every: bool = typer.Option(False, "--all", help="every page, one after the other"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """The event log: presence, control, commands, alarms; oldest first."""
    if kind is not None and kind not in EVENT_KINDS:
        fail(f"--kind is one of {', '.join(EVENT_KINDS)}; not {kind!r}")
    start, end = window(since, until)

    async def act(fleet: FleetClient) -> dict[str, Any]:
        vehicle_id = await fleet.vehicle_id_of(vehicle) if vehicle else None
        cursor, got = after, []
        while True:
            page = await fleet.event_log(
                vehicle_id=vehicle_id, kind=kind, since=start, until=end, limit=limit, after=cursor
            )
            got.extend(page["events"])
            cursor = page.get("next_after")
            if not every or cursor is None:
                return {"events": got, "next_after": cursor}

    data = run(server, token, act)
    if as_json:
        dump(data)
        return
    for event in data["events"]:
        answer_line(f"{event['at']} {event.get('vehicle_id') or '-'} {event_text(event)}")
    if data["next_after"] is not None:
        errors.print(
            f"more events: the same command with --after {data['next_after']} (or --all)",
            markup=False,
            highlight=False,
        )


def _writable(path: str | Path, what: str = "-o") -> None:
    """A file to write whose folder exists, checked before anything is asked of the server
    (bad arguments: one line, exit 2)."""
    if str(path) == "-":
        return
    folder = Path(path).parent
    if not folder.is_dir():
        fail(f"cannot write {path} ({what}): there is no folder {folder}")


def export(
    vehicle: str = VehicleArg,
    since: str | None = SinceOpt,
    until: str | None = UntilOpt,
    fmt: str | None = typer.Option(
        None,
        "--format",
        help="jsonl (a sample per line) or csv (default: from -o's ending, else jsonl)",
    ),
    output: str = typer.Option("-", "--output", "-o", help="file to write; -: stdout"),
    page: int = typer.Option(10_000, min=1, max=10_000, help="samples per request"),
    server: str = ServerOpt,
    token: str = TokenOpt,
) -> None:
    """Every stored telemetry sample of a vehicle, in seq order, page by page."""
    fmt = file_format(output, fmt, streams.EXPORT_FORMATS)
    start, end = window(since, until)
    _writable(output)
    # A file is written beside the target and takes its place once every page is in: a
    # refusal or a lost link half way leaves a former file as it was, and no new one. A
    # pipe or a device (/dev/stdout) is written as it comes.
    target = Path(output)
    in_place = output == "-" or (target.exists() and not target.is_file())
    part = None if in_place else target.with_name(f".{target.name}.part")
    with contextlib.ExitStack() as stack:
        try:
            out = (
                sys.stdout
                if output == "-"
                else stack.enter_context(open(part or target, "w", newline=""))
            )
        except OSError as exc:
            fail(f"cannot write {output}: {exc.strerror or exc}")

        async def act(fleet: FleetClient) -> int:
            vehicle_id = await fleet.vehicle_id_of(vehicle)
            pages = fleet.telemetry_pages(vehicle_id, since=start, until=end, page=page)
            return await streams.export_samples(pages, fmt, out)

        try:
            count = run(server, token, act)
        except BaseException:
            if part is not None:
                stack.close()
                part.unlink(missing_ok=True)
            raise
    if part is not None:
        try:
            part.replace(output)
        except OSError as exc:
            part.unlink(missing_ok=True)
            fail(f"cannot write {output}: {exc.strerror or exc}")
    if output != "-":
        errors.print(f"{count} samples written to {output}", markup=False, highlight=False)


def track(
    vehicle: str = VehicleArg,
    since: str | None = SinceOpt,
    until: str | None = UntilOpt,
    fmt: str | None = typer.Option(
        None, "--format", help=f"{', '.join(FORMATS)} (default: from -o's ending, else json)"
    ),
    output: str = typer.Option("-", "--output", "-o", help="file to write; -: stdout"),
    max_points: int | None = typer.Option(
        None, min=2, max=10_000, help="downsample to this many points, keeping the shape"
    ),
    server: str = ServerOpt,
    token: str = TokenOpt,
) -> None:
    """A vehicle's track as JSON, GeoJSON, GPX, CSV or a PNG plot.

    The window defaults to the last 24 h. Long tracks come page by page, with a
    progress bar on a terminal.
    """
    fmt = file_format(output, fmt, FORMATS)
    if fmt == "png" and output == "-":
        fail("a PNG needs a file: give -o FILE.png")
    now = datetime.now(UTC)
    start, end = window(since, until, now)
    end = end or format_ts(now)
    start = start or format_ts(parse_ts(end) - DEFAULT_WINDOW)
    if parse_ts(start) >= parse_ts(end):
        fail(f"the window is empty: {start} is not before {end}")
    _writable(output)

    async def act(fleet: FleetClient) -> tuple[str, TrackJoiner]:
        vehicle_id = await fleet.vehicle_id_of(vehicle)
        wire = "json" if fmt == "png" else fmt
        points = PNG_POINTS if fmt == "png" and max_points is None else max_points
        joined = TrackJoiner(wire)
        pages = fleet.track_pages(vehicle_id, since=start, until=end, fmt=wire, max_points=points)
        with _track_progress() as bar:
            task = bar.add_task("track", total=1.0, points=0)
            async for page in pages:
                joined.add(page.content)
                reached = page.next_from or end
                bar.update(task, completed=_fraction(start, reached, end), points=joined.points)
        return vehicle_id, joined

    vehicle_id, joined = run(server, token, act)
    if fmt == "png":
        title = f"{vehicle_id}: {start[:16]} to {end[:16]} UTC ({joined.points} points)"
        try:
            plot_png(joined.json_points(), title, output)
        except RuntimeError as exc:
            fail(str(exc))
    elif output == "-":
        sys.stdout.write(joined.text())
    else:
        try:
            Path(output).write_text(joined.text())
        except OSError as exc:
            fail(f"cannot write {output}: {exc.strerror or exc}")
    if output != "-":
        errors.print(
            f"{joined.points} points of {vehicle_id} written to {output}",
            markup=False,
            highlight=False,
        )


def sync(
    vehicles: list[str] = typer.Argument(..., help="vehicle ids or names"),
    db: Path = typer.Option(Path("fleet.sqlite"), help="the local copy (SQLite; made if new)"),
    since: str | None = typer.Option(
        None, "--since", "--from", help="only samples from then on (10m, 2h, ISO 8601)"
    ),
    full: bool = typer.Option(
        False, "--full", help="read every sample again, storing those missing (slower)"
    ),
    page: int = typer.Option(10_000, min=1, max=10_000, help="samples per request"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Keep a local SQLite copy of vehicles' telemetry, for offline work.

    Each run adds the samples stored since the last one (each sample once, keyed by
    vehicle and seq). Safe to interrupt: the next run goes on from there.
    """
    start, _ = window(since, None)
    _writable(db, "--db")

    async def act(fleet: FleetClient) -> list[SyncResult]:
        chosen = await fleet.resolve_vehicles(vehicles)
        done = []
        with LocalCopy(db) as copy, _count_progress() as bar:
            for vehicle in chosen:
                task = bar.add_task(vehicle["vehicle_id"], count=0)

                def counted(n: int, task: Any = task) -> None:
                    bar.update(task, count=n)

                done.append(
                    await sync_vehicle(
                        fleet, copy, vehicle, since=start, full=full, page=page, progress=counted
                    )
                )
        return done

    results = run(server, token, act)
    if as_json:
        dump({"db": str(db), "vehicles": [r.__dict__ for r in results]})
        return
    for r in results:
        held = f"{r.total} in {db} (through seq {r.through_seq})"
        answer_line(f"{r.vehicle_id}: {r.added} new sample{'' if r.added == 1 else 's'}; {held}")


def _fraction(start: str, reached: str, end: str) -> float:
    whole = (parse_ts(end) - parse_ts(start)).total_seconds()
    done = (parse_ts(reached) - parse_ts(start)).total_seconds()
    return min(max(done / whole, 0.0), 1.0) if whole > 0 else 1.0


def _track_progress() -> Progress:
    """A bar over the window's time on stderr (when it is a terminal)."""
    return Progress(
        TextColumn("track"),
        BarColumn(),
        TaskProgressColumn(),
        TextColumn("{task.fields[points]} points"),
        TimeElapsedColumn(),
        console=errors,
        transient=True,
        disable=not errors.is_terminal,
    )


def _count_progress() -> Progress:
    return Progress(
        SpinnerColumn(),
        TextColumn("{task.description}: {task.fields[count]} new samples"),
        TimeElapsedColumn(),
        console=errors,
        transient=True,
        disable=not errors.is_terminal,
    )
