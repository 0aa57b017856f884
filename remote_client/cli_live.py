"""``fleetctl watch`` and ``fleetctl publish``: topics, live (``docs/live.md``)."""

from __future__ import annotations

import asyncio
import contextlib
import json
from typing import Any

import typer
import websockets

from fleet_protocol.topics import validate_topic
from remote_client import streams
from remote_client.cli_common import JsonOpt, ServerOpt, TokenOpt, fail, finite, run, say
from remote_client.output import errors
from remote_client.sdk import FleetApiError, FleetClient, UnknownVehicle, pick_vehicle

__all__ = ["publish", "watch"]


def watch(
    topics: list[str] = typer.Argument(None, help="topics to follow; none: fleet"),
    count: int | None = typer.Option(
        None,
        min=1,
        help="stop after this many lines are printed (--json: events, a line each)",
    ),
    seconds: float | None = typer.Option(None, min=0, callback=finite, help="stop after this long"),
    throttle_ms: int = typer.Option(0, min=0, help="at most one event per topic per N ms"),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Follow topics live, a readable line at a time (--json: a line per event).

    Each topic's current state comes first, then every change. A line is a vehicle of the
    fleet, a command of a vehicle's list, a sample, an entry of its event log: --count
    counts these lines. Topics: fleet (presence), vehicle/VEHICLE/telemetry, .../commands,
    .../control, .../events (VEHICLE: an id or a name), or any topic a unit publishes.
    Ctrl-C stops.
    """
    wanted = list(topics or ["fleet"])
    for topic in wanted:  # all but a vehicle's name (any text), before any look-up
        _checked(topic, _vehicle_as_id(topic))
    if any(_names_a_vehicle(t) for t in wanted):
        wanted = run(server, token, lambda fleet: _vehicle_topics(fleet, wanted))
    for topic in wanted:
        _checked(topic)
    with contextlib.suppress(KeyboardInterrupt):
        follow = streams.Follow(wanted, throttle_ms, count, seconds, as_json)
        asyncio.run(streams.watch(FleetClient(server, token), follow))


def _names_a_vehicle(topic: str) -> bool:
    parts = topic.split("/")
    return len(parts) >= 3 and parts[0] == "vehicle"


def _vehicle_as_id(topic: str) -> str:
    """``topic`` with the vehicle it names (an id or a name) as an id would be: what is
    left to check before the name is looked up."""
    if not _names_a_vehicle(topic):
        return topic
    head, _, rest = topic.split("/", 2)
    return f"{head}/v/{rest}"


async def _vehicle_topics(fleet: FleetClient, topics: list[str]) -> list[str]:
    """``vehicle/<id or name>/...`` with the vehicle's id (one look-up for all). A segment
    that names no vehicle the caller sees is left for the server to judge."""
    fleet_now = (await fleet.vehicles())["vehicles"]
    out = []
    for topic in topics:
        if _names_a_vehicle(topic):
            head, ref, rest = topic.split("/", 2)
            try:
                ref = pick_vehicle(ref, fleet_now)["vehicle_id"]
            except UnknownVehicle:
                try:  # no vehicle goes by that name: is it an id one could register?
                    validate_topic(topic)
                except ValueError as exc:
                    fail(f"not a topic: {topic!r}: no vehicle you can see goes by {ref!r}, "
                         f"and as a vehicle id: {exc}")  # fmt: skip
                if await _may_see_later(fleet, ref):  # else the server's refusal says it
                    errors.print(  # an admin's watch would otherwise wait in silence
                        f"warning: no vehicle {ref!r} among those you can see: {topic} has "
                        "nothing to show until one registers under that id",
                        style="yellow",
                        markup=False,
                        highlight=False,
                    )
            topic = f"{head}/{ref}/{rest}"
        out.append(topic)
    return out


async def _may_see_later(fleet: FleetClient, vehicle_id: str) -> bool:
    """Whether the caller would see a vehicle ``vehicle_id`` that registers later: an
    admin sees every vehicle, another user those of its list. Any other caller (one
    /api/me does not answer) is not told it may: the server judges its watch."""
    try:
        me = await fleet.me()
    except FleetApiError:
        return False
    return me.get("role") == "admin" or vehicle_id in (me.get("vehicles") or ())


def publish(
    topic: str = typer.Argument(..., help="a topic you may write: user/YOU/..."),
    data: str = typer.Argument(
        ..., help="the message, as JSON: '{\"depth_m\": 12.5}', 42, '\"text\"'"
    ),
    server: str = ServerOpt,
    token: str = TokenOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Publish one message on a topic, to whoever subscribes to it.

    A unit, a worker or another operator's watch may subscribe. A user writes under
    user/ITS-NAME/.
    """
    _checked(topic)
    try:
        message: Any = json.loads(data, parse_constant=_no_constant)
    except ValueError as exc:
        fail(f"DATA is JSON (quote a text: '\"{data}\"'): {exc}")

    async def act(fleet: FleetClient) -> dict[str, Any]:
        try:
            await fleet.publish(topic, message)
        except (OSError, websockets.WebSocketException) as exc:
            errors.print(f"cannot reach {server}: {exc}", style="red", markup=False)
            raise typer.Exit(3) from None
        return {"topic": topic, "published": True}

    say(run(server, token, act), as_json, f"published on {topic}")


def _checked(topic: str, checked: str | None = None) -> None:
    """As the server checks a topic (``checked``, when given, stands for it): a bad one is
    a bad argument (exit 2)."""
    try:
        validate_topic(topic if checked is None else checked)
    except ValueError as exc:
        fail(f"not a topic: {topic!r}: {exc}")


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a JSON number")
