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


#: Waits between reconnections of ``watch`` after a lost link (the last one repeats).
RECONNECT_S = (0.5, 1.0, 2.0, 5.0, 10.0)


class _Refused(Exception):
    """The server refused the token or the subscription: no use trying again."""


async def watch(
    server: str,
    token: str,
    subscribe: dict[str, Any],
    count: int | None,
    seconds: float | None,
    as_json: bool,
) -> None:
    """Send ``subscribe`` on ``/ws/client`` and print each event until ``count`` events or
    ``seconds``. A lost link is taken up again and each topic's current state comes first
    again (the changes while the link was down are not replayed: ``export`` has every
    sample); a refusal is exit 1, a server not reachable at the start exit 3."""
    url = server.replace("https://", "wss://", 1).replace("http://", "ws://", 1) + "/ws/client"
    seen = [0]
    failures = 0
    try:
        async with asyncio.timeout(seconds):
            while True:
                try:
                    if await _follow(url, token, subscribe, count, seen, as_json):
                        return
                    failures = 0  # it ran: the next loss starts the waits again
                    reason = "the server closed the connection"
                except _Refused as exc:
                    errors.print(str(exc), style="red", markup=False)
                    raise typer.Exit(1) from None
                except (OSError, TimeoutError, websockets.InvalidHandshake) as exc:
                    if seen[0] == 0 and failures == 0:
                        errors.print(f"cannot reach {server}: {exc}", style="red", markup=False)
                        raise typer.Exit(3) from None
                    reason = f"{type(exc).__name__}: {exc}"
                wait = RECONNECT_S[min(failures, len(RECONNECT_S) - 1)]
                failures += 1
                errors.print(f"link lost ({reason}); again in {wait:g} s", markup=False)
                await asyncio.sleep(wait)
    except TimeoutError:
        return  # --seconds is over


async def _follow(
    url: str,
    token: str,
    subscribe: dict[str, Any],
    count: int | None,
    seen: list[int],
    as_json: bool,
) -> bool:
    """One connection: True when ``count`` events were printed, False when it closed."""
    headers = {"Authorization": f"Bearer {token}"}
    async with websockets.connect(url, additional_headers=headers, open_timeout=30) as ws:
        try:
            await ws.send(json.dumps(subscribe))
            async for frame in ws:
                if not isinstance(frame, str):
                    continue  # media: binary frames are not printed
                push = json.loads(frame)
                if push.get("op") == "ack" and not push.get("ok"):
                    err = push.get("error") or {}
                    raise _Refused(f"{err.get('code')}: {err.get('message')}")
                if push.get("op") == "lagging":
                    errors.print(f"{push.get('dropped')} events dropped (too slow)", markup=False)
                if push.get("op") != "event":
                    continue
                print_event(push, as_json)
                seen[0] += 1
                if count is not None and seen[0] >= count:
                    return True
        except websockets.ConnectionClosed as exc:
            if exc.rcvd is not None and exc.rcvd.code in (4401, 4403):
                raise _Refused(f"refused: {exc.rcvd.reason}") from None
        return False


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
