"""What every ``fleetctl`` command shares: its options, the session it runs in, exit codes,
and printing answers for people or for scripts.

Exit codes: 0 done; 1 the server (or the fleet, for a vehicle name nobody goes by)
refused; 2 a server error or bad arguments (an ambiguous name among them);
3 the server cannot be reached; 141 (128 + SIGPIPE, as a Unix tool's) nobody reads
the answer any more (``fleetctl watch | head -1``).
"""

from __future__ import annotations

import asyncio
import json
import math
from collections.abc import Awaitable, Callable, Coroutine, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Final, NoReturn, TypeVar

import httpx
import typer
from pydantic import BaseModel, ValidationError
from typer.core import TyperGroup

from fleet_protocol.common import ID_PATTERN, ID_RULE
from fleet_protocol.errors import error_text
from fleet_protocol.links import server_root_problem
from remote_client import streams
from remote_client.output import OutputClosed, answer_line, console, errors, quiet_stdout
from remote_client.sdk import AmbiguousName, FleetApiError, FleetClient
from remote_client.times import BadTime, when_text

#: Help texts are Markdown: a paragraph is reflowed to the terminal's width (typer's rich
#: mode kept each line break of a docstring, so sentences broke in the middle).
HELP_MARKUP: Final = "markdown"


def server_url(ctx: typer.Context, param: typer.CallbackParam, value: str) -> str:
    """The callback of ``--server``: the server's root as an http:// or https:// URL
    (``http://127.0.0.1:8000``), else a bad argument naming where it came from, --server
    or FLEET_SERVER (exit 2; it was taken for a server out of reach, or asked for
    /api/api/... and answered 404)."""
    source = ctx.get_parameter_source(param.name or "server")
    given = "FLEET_SERVER" if source is not None and source.name == "ENVIRONMENT" else "--server"
    if (problem := server_root_problem(value)) is not None:
        fail(f"{given} is {problem}")
    return value


ServerOpt = typer.Option(
    "http://127.0.0.1:8000", envvar="FLEET_SERVER", callback=server_url, help="server URL"
)
TokenOpt = typer.Option(..., envvar="FLEET_TOKEN", help="API token (FLEET_TOKEN)")
JsonOpt = typer.Option(False, "--json", help="print JSON for scripts")
VehicleArg = typer.Argument(..., help="vehicle id or name (its current instance), or instance id")
#: The token of a group whose bare form lists (``fleetctl users``): optional there, since
#: ``--help`` and the subcommands take their own.
GroupTokenOpt = typer.Option(None, envvar="FLEET_TOKEN", help="API token (FLEET_TOKEN)")
SinceOpt = typer.Option(
    None, "--since", "--from", help="start: 10m, 2h, 1d (that long ago), or ISO 8601 (inclusive)"
)
UntilOpt = typer.Option(
    None, "--until", "--to", help="end: 10m, 2h (that long ago), now, or ISO 8601 (exclusive)"
)

T = TypeVar("T")

#: Exit codes.
REFUSED, FAILED, UNREACHABLE, OUTPUT_CLOSED = 1, 2, 3, 128 + 13


class Commands(TyperGroup):
    """``fleetctl``'s commands. One whose stdout is closed (its reader has gone) stops at
    once, quietly, with exit 141, as a Unix tool ended by SIGPIPE does."""

    def invoke(self, ctx: Any) -> Any:  # a click Context (typer's own click: typer._click)
        try:
            return super().invoke(ctx)
        except (OutputClosed, BrokenPipeError):
            quiet_stdout()
            raise typer.Exit(OUTPUT_CLOSED) from None


def run(server: str, token: str, action: Callable[[FleetClient], Awaitable[T]]) -> T:
    """``action`` on a :class:`FleetClient` session; a refusal or a network failure is
    printed on stderr and becomes the exit code."""

    async def session() -> T:
        async with FleetClient(server, token) as fleet:
            return await action(fleet)

    return handled(server, session)


def handled(server: str, work: Callable[[], Coroutine[Any, Any, T]]) -> T:
    """``work`` run; a refusal or a network failure printed on stderr and made the exit
    code (as :func:`run` does)."""
    try:
        return asyncio.run(work())
    except httpx.HTTPError as exc:
        errors.print(f"cannot reach {server}: {exc}", style="red", markup=False)
        raise typer.Exit(UNREACHABLE) from None
    except AmbiguousName as exc:
        streams.print_refusal(exc)
        raise typer.Exit(FAILED) from None
    except FleetApiError as exc:
        streams.print_refusal(exc)
        raise typer.Exit(REFUSED if exc.status < 500 else FAILED) from None


def list_when_bare(
    ctx: typer.Context,
    server: str,
    token: str | None,
    as_json: bool,
    show: Callable[[str, str, bool], None],
) -> None:
    """A group's callback: with no subcommand, ``show`` its list (a token needed)."""
    if ctx.invoked_subcommand is not None:
        return
    if token is None:
        fail("give a token: --token or FLEET_TOKEN")
    show(server, token, as_json)


def fail(message: str) -> NoReturn:
    """Bad arguments: the message on stderr (one line, however long), exit 2."""
    errors.print(message, style="red", markup=False, highlight=False, soft_wrap=True)
    raise typer.Exit(FAILED)


def finite(param: typer.CallbackParam, value: float | None) -> float | None:
    """The callback of every float a command takes: NaN and the infinities are bad
    arguments (no position, distance, speed or time is one, and JSON cannot carry them)."""
    if value is not None and not math.isfinite(value):
        fail(f"{_shown_name(param)} is a finite number, not {value}")
    return value


def between(
    low: float, high: float, *, above: bool = False
) -> Callable[[typer.CallbackParam, float | None], float | None]:
    """The callback of a number from ``low`` (or above it, ``above``) to ``high``, as the
    server takes it: refused here, exit 2, before anything is sent."""

    def check(param: typer.CallbackParam, value: float | None) -> float | None:
        finite(param, value)
        if value is None:
            return None
        name = _shown_name(param)
        if value <= low if above else value < low:
            fail(f"{name} is {'above' if above else 'at least'} {low:g}, not {value:g}")
        if value > high:
            fail(f"{name} is at most {high:g}, not {value:g}")
        return value

    return check


def sent_as(
    model: type[BaseModel], field: str
) -> Callable[[typer.CallbackParam, str | None], str | None]:
    """The callback of an argument the server takes as ``model``'s ``field`` (a username,
    a vehicle's or a gateway's id): checked here by the protocol's own model, and refused
    in words (exit 2) before anything is sent."""

    def check(param: typer.CallbackParam, value: str | None) -> str | None:
        if value is None:
            return None
        try:
            model.model_validate({field: value})
        except ValidationError as exc:
            for error in exc.errors():
                if error["loc"] == (field,):
                    fail(_refused(_shown_name(param), value, error))
        return value

    return check


def _refused(name: str, value: str, error: Any) -> str:
    """Why the server would refuse ``value``, in words (an identifier's pattern too)."""
    if error["type"] == "string_pattern_mismatch" and error["ctx"]["pattern"] == ID_PATTERN:
        return f"{name} is {ID_RULE}, not {value!r}"
    return f"{name} {value!r}: {error_text(error)}"


def latitude(param: typer.CallbackParam, value: float | None) -> float | None:
    """A latitude argument: from -90 to 90 (refused here, before anything is sent)."""
    finite(param, value)
    if value is not None and not -90 <= value <= 90:
        fail(f"{_shown_name(param)} is a latitude, from -90 to 90, not {value}")
    return value


def longitude(param: typer.CallbackParam, value: float | None) -> float | None:
    """A longitude argument: from -180 to 180 (refused here, before anything is sent)."""
    finite(param, value)
    if value is not None and not -180 <= value <= 180:
        fail(f"{_shown_name(param)} is a longitude, from -180 to 180, not {value}")
    return value


def lat_lon(text: str) -> tuple[float, float]:
    """``LAT,LON``: a latitude (-90 to 90) and a longitude (-180 to 180); ValueError when
    it is not that."""
    lat, lon = (float(part) for part in text.split(","))
    if not (math.isfinite(lat) and math.isfinite(lon)):
        raise ValueError(f"not finite: {text!r}")
    if not (-90 <= lat <= 90 and -180 <= lon <= 180):
        raise ValueError(f"out of range: {text!r}")
    return lat, lon


def position(lat_text: str, lon_text: str) -> tuple[float, float]:
    """``LAT`` and ``LON`` given as the last two of a command's arguments: checked as
    :func:`latitude` and :func:`longitude` check theirs (exit 2, nothing sent)."""
    values = []
    for name, text, high in (("LAT", lat_text, 90), ("LON", lon_text, 180)):
        try:
            value = float(text)
        except ValueError:
            fail(f"{name} is a number, not {text!r}")
        if not math.isfinite(value):
            fail(f"{name} is a finite number, not {value}")
        if not -high <= value <= high:
            what = "latitude" if high == 90 else "longitude"
            fail(f"{name} is a {what}, from -{high} to {high}, not {value}")
        values.append(value)
    return values[0], values[1]


def split_waypoints(targets: Sequence[str]) -> tuple[list[str], list[str]]:
    """``VEHICLE... LAT,LON...``: the vehicles (the arguments before the first that reads
    as a pair: a number, a comma) and the waypoints (that one and all after it)."""
    for index, text in enumerate(targets):
        if _numeric(text.split(",", 1)[0]):
            if "," not in text:
                fail(f"not a LAT,LON pair (-90 to 90, -180 to 180): {text!r}")
            if index == 0:
                fail("give a vehicle (or more) before the waypoints")
            return list(targets[:index]), list(targets[index:])
    fail("give a vehicle (or more), then the waypoints as LAT,LON pairs")


def _numeric(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _shown_name(param: typer.CallbackParam) -> str:
    """``--radius`` for an option, ``LAT`` for an argument."""
    return param.opts[0] if param.param_type_name == "option" else str(param.name).upper()


def file_format(output: str, fmt: str | None, formats: Sequence[str]) -> str:
    """The format to write: ``--format``'s, else the one ``-o``'s ending names (``.gpx``:
    gpx), else, on stdout (``-``), the first of ``formats``. A format not among them, or
    a file whose ending names none without ``--format``, is a bad argument."""
    if fmt is None and output != "-":
        fmt = Path(output).suffix.lower().removeprefix(".")
        if fmt not in formats:
            endings = ", ".join(f".{f}" for f in formats)
            fail(f"-o {output} names no format: end it in one of {endings}, or give --format")
    fmt = fmt or formats[0]
    if fmt not in formats:
        fail(f"--format is one of {', '.join(formats)}, not {fmt!r}")
    return fmt


def window(
    since: str | None, until: str | None, now: datetime | None = None
) -> tuple[str | None, str | None]:
    """``--since`` / ``--until`` as the wire's times (one ``now`` for both)."""
    now = now or datetime.now(UTC)
    try:
        start, end = when_text(since, now), when_text(until, now)
    except BadTime as exc:
        fail(str(exc))
    if start is not None and end is not None and start >= end:  # one format: text order
        fail(
            f"the window is empty: --since {since} ({start}) is not before --until {until} ({end})"
        )
    return start, end


def say(data: Any, as_json: bool, text: str) -> None:
    """The answer: its JSON for scripts, else ``text`` for people (shown escaped)."""
    if as_json:
        dump(data)
    else:
        answer_line(text)


def new_token(data: dict[str, Any], as_json: bool, what: str, variable: str) -> None:
    """A new token, shown this once: alone on stdout (for ``$(...)``), what it is on
    stderr; ``--json``: the whole answer."""
    if as_json:
        dump(data)
        return
    errors.print(
        f"{what}. Its token, shown this once (give it as {variable}):",
        markup=False,
        highlight=False,
    )
    answer_line(data["token"])


def dump(data: Any) -> None:
    """JSON for scripts, as ``json`` writes it: ASCII, control characters escaped."""
    print(json.dumps(data, indent=2))


def boat(view: dict[str, Any]) -> str:
    """A vehicle as people know it: its name and its id (``H2OmniX Alpha (usv-1)``), the id
    alone when it has no other name. ``view``: any answer naming a vehicle and its name."""
    name, vehicle_id = view.get("name"), view["vehicle_id"]
    return f"{name} ({vehicle_id})" if name and name != vehicle_id else str(vehicle_id)


async def with_names(fleet: FleetClient, data: dict[str, Any]) -> dict[str, Any]:
    """A submit's answer and, for :func:`print_queued`, the name of each instance's boat
    (``_names``: not part of the answer, never in ``--json``)."""
    try:
        names = await fleet.instance_names()
    except FleetApiError:
        names = {}  # the command went; its lines show the instance ids alone
    return {**data, "_names": names}


def print_queued(data: dict[str, Any], as_json: bool) -> None:
    names: dict[str, str] = data.pop("_names", None) or {}
    if as_json:
        dump(data)
        return
    for c in data["commands"]:
        iid = c["instance_id"]
        boat = f"{names[iid]} ({iid})" if iid in names else iid
        console.print(f"{boat}: {c['command_id']} {c['status']}", highlight=False, markup=False)
    for warning in data.get("warnings") or []:
        errors.print(f"warning: {warning}", style="yellow", markup=False, highlight=False)
