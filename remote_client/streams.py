"""``fleetctl``'s long-running commands: ``watch`` (a live socket) and ``export`` (paging)."""

from __future__ import annotations

import asyncio
import contextlib
import csv
import json
import logging
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import IO, Any

import httpx
import typer
import websockets
from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

from remote_client.lines import event_lines
from remote_client.output import answer_line, errors, reader_watched
from remote_client.sdk import FleetApiError, FleetClient

log = logging.getLogger(__name__)

#: ``export``'s formats, each also the file name ending that chooses it; the first on stdout.
EXPORT_FORMATS = ("jsonl", "csv")
#: CSV columns of ``export``: the sample's fields, then ``data`` as JSON text.
SAMPLE_COLUMNS = ("seq", "ts", "lat", "lon", "depth_m", "heading_deg", "speed_mps", "battery_pct")


async def export_samples(pages: AsyncIterator[list[dict[str, Any]]], fmt: str, out: IO[str]) -> int:
    """Write every page as JSON lines or CSV; the number of samples. A spinner with the
    count runs on stderr when it is a terminal."""
    writer = csv.writer(out) if fmt == "csv" else None
    if writer is not None:
        writer.writerow([*SAMPLE_COLUMNS, "data"])
    count = 0
    columns = (SpinnerColumn(), TextColumn("{task.fields[count]} samples"), TimeElapsedColumn())
    with Progress(*columns, console=errors, transient=True, disable=not errors.is_terminal) as bar:
        task = bar.add_task("export", count=0)
        async for samples in pages:
            for sample in samples:
                if writer is None:
                    out.write(json.dumps(sample, separators=(",", ":")) + "\n")
                else:
                    extra = sample.get("data")
                    row = [sample.get(k) for k in SAMPLE_COLUMNS]
                    writer.writerow([*row, json.dumps(extra) if extra is not None else ""])
            count += len(samples)
            bar.update(task, count=count)
    return count


def print_refusal(exc: FleetApiError) -> None:
    """The error envelope on stderr: status, code, message, then a line per detail."""
    errors.print(f"{exc.status} {exc.code}: {exc.message}", style="red", markup=False)
    for detail in exc.details:
        where = detail.get("instance_id") or detail.get("field") or ""
        errors.print(f"  {where}: {detail.get('message', '')}", markup=False, highlight=False)


#: Waits between reconnections of ``watch`` after a lost link (the last one repeats).
RECONNECT_S = (0.5, 1.0, 2.0, 5.0, 10.0)


@dataclass(frozen=True)
class Follow:
    """What ``watch`` follows and when it stops: after ``count`` lines (an event is one or
    more, :func:`print_event`), or ``seconds``."""

    topics: list[str]
    throttle_ms: int = 0
    count: int | None = None
    seconds: float | None = None
    as_json: bool = False


async def watch(fleet: FleetClient, follow: Follow) -> None:
    """Print each event of ``follow.topics`` until ``count`` lines or ``seconds``. A lost
    link is taken up again and each topic's current state comes first again (the changes
    while the link was down are not replayed: ``export`` has every sample); a refusal is
    exit 1, a server not reachable at the start exit 3; stdout closed (OutputClosed) ends
    it, not taken for a lost link, and so does its reader going away while nothing is
    printed (``output.reader_watched``). While it runs, the leases the caller holds are
    kept alive (``FleetClient.keep_leases_alive``)."""
    try:
        with reader_watched():
            await _follow(fleet, follow)
    except TimeoutError:
        return  # --seconds is over


async def _follow(fleet: FleetClient, follow: Follow) -> None:
    """:func:`watch`'s loop; TimeoutError when ``--seconds`` is over."""
    printed = failures = 0
    seen = False  # an event came: a link lost after it is taken up again
    async with fleet, asyncio.timeout(follow.seconds), _leases_kept(fleet):
        while True:
            try:
                async for push in fleet.events(follow.topics, throttle_ms=follow.throttle_ms):
                    if push["op"] == "lagging":
                        errors.print(f"{push.get('dropped')} events dropped (too slow)")
                        continue
                    left = None if follow.count is None else follow.count - printed
                    printed += print_event(push, follow.as_json, left)
                    seen = True
                    if follow.count is not None and printed >= follow.count:
                        return
                failures = 0  # it ran: the next loss starts the waits again
                reason = "the server closed the connection"
            except FleetApiError as exc:
                print_refusal(exc)
                raise typer.Exit(1) from None
            except (OSError, TimeoutError, websockets.InvalidHandshake) as exc:
                if not seen and failures == 0:
                    errors.print(f"cannot reach {fleet.server}: {exc}", style="red", markup=False)
                    raise typer.Exit(3) from None
                reason = f"{type(exc).__name__}: {exc}"
            wait = RECONNECT_S[min(failures, len(RECONNECT_S) - 1)]
            failures += 1
            errors.print(f"link lost ({reason}); again in {wait:g} s", markup=False)
            await asyncio.sleep(wait)


@contextlib.asynccontextmanager
async def _leases_kept(fleet: FleetClient) -> AsyncIterator[None]:
    """Heartbeats for the caller's leases in the background while the block runs; a
    failed round is tried again a little later (watching goes on regardless)."""

    async def keep() -> None:
        while True:
            try:
                await fleet.keep_leases_alive()
            except (FleetApiError, httpx.HTTPError, KeyError) as exc:
                log.debug("lease heartbeat: %s", exc)
                await asyncio.sleep(5.0)

    task = asyncio.create_task(keep())
    try:
        yield
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


def print_event(push: dict[str, Any], as_json: bool, limit: int | None = None) -> int:
    """An event as one JSON line (``--json``), or as readable lines (``remote_client.lines``:
    one per event; the ``fleet`` topic's current state, one per vehicle; a vehicle's
    commands, one per command): at most ``limit`` of them. The lines printed."""
    lines = [json.dumps(push)] if as_json else event_lines(push)
    for line in lines[:limit]:
        answer_line(line)
    return len(lines[:limit])
