"""``fleetctl``'s long-running commands: ``watch`` (a live socket) and ``export`` (paging)."""

from __future__ import annotations

import asyncio
import csv
import json
from collections.abc import Callable
from typing import IO, Any

import typer
import websockets
from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

from remote_client.output import errors

#: CSV columns of ``export``: the sample's fields, then ``data`` as JSON text.
SAMPLE_COLUMNS = ("seq", "ts", "lat", "lon", "depth_m", "heading_deg", "speed_mps", "battery_pct")


def export_samples(
    fetch: Callable[[dict[str, Any]], dict[str, Any]], query: dict[str, Any], fmt: str, out: IO[str]
) -> int:
    """Write every page ``fetch`` returns (``after_seq`` moved on) as JSON lines or CSV; the
    number of samples. A spinner with the count runs on stderr when it is a terminal."""
    writer = csv.writer(out) if fmt == "csv" else None
    if writer is not None:
        writer.writerow([*SAMPLE_COLUMNS, "data"])
    count = 0
    columns = (SpinnerColumn(), TextColumn("{task.fields[count]} samples"), TimeElapsedColumn())
    with Progress(*columns, console=errors, transient=True, disable=not errors.is_terminal) as bar:
        task = bar.add_task("export", count=0)
        while True:
            data = fetch(query)
            for sample in data["samples"]:
                if writer is None:
                    out.write(json.dumps(sample, separators=(",", ":")) + "\n")
                else:
                    extra = sample.get("data")
                    row = [sample.get(k) for k in SAMPLE_COLUMNS]
                    writer.writerow([*row, json.dumps(extra) if extra is not None else ""])
            count += len(data["samples"])
            bar.update(task, count=count)
            if data.get("next_after_seq") is None:
                return count
            query = {**query, "after_seq": data["next_after_seq"]}


async def watch(
    server: str,
    token: str,
    subscribe: dict[str, Any],
    count: int | None,
    seconds: float | None,
    as_json: bool,
) -> None:
    """Send ``subscribe`` on ``/ws/client`` and print each event until ``count`` events,
    ``seconds``, or the server closes (a refusal: exit 1; a lost link: exit 3)."""
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
                print_event(push, as_json)
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


def print_event(push: dict[str, Any], as_json: bool) -> None:
    """An event as one JSON line, or for people: time, topic, data (``fleet``: a line per
    vehicle)."""
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
