"""``fleet-server``: run the cloud server. ``--help`` lists every FLEET_* setting."""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
from typing import TYPE_CHECKING, Any

import typer
import uvicorn
from pydantic import ValidationError

from server.logs import log_config
from server.settings import Settings, env_name, refusals

if TYPE_CHECKING:
    from fastapi import FastAPI


def _settings_help() -> str:
    lines = ["\b", "Settings come from FLEET_* environment variables (or a .env file):"]
    for name, field in Settings.model_fields.items():
        default: Any = field.default
        if default is None:
            default = "unset"
        lines.append(f"  {env_name(name):<33} {field.description} [default: {default}]")
    return "\n\n".join(["Run the fleet-cloud server.", "\n".join(lines)])


app = typer.Typer(add_completion=False, help=_settings_help(), rich_markup_mode=None)


@app.command(help=_settings_help())
def serve(
    host: str | None = typer.Option(None, help="address to listen on (FLEET_HOST)"),
    port: int | None = typer.Option(None, help="port to listen on (FLEET_PORT)"),
) -> None:
    overrides: dict[str, Any] = {}
    if host is not None:
        overrides["host"] = host
    if port is not None:
        overrides["port"] = port
    run(load_settings(**overrides))


def load_settings(**overrides: Any) -> Settings:
    """The settings from the environment (and ``.env``), ``overrides`` (the command line's
    options) over them. A bad one is a line on stderr naming its variable (or option) and
    what it takes, and exit 2."""
    try:
        return Settings(**overrides)
    except ValidationError as exc:
        for field, problem in refusals(exc).items():
            name = f"--{field}" if field in overrides else env_name(field)
            typer.echo(f"{name}: {problem}", err=True)
        raise SystemExit(2) from None


def run(settings: Settings, app: FastAPI | None = None) -> None:
    """Serve ``app`` (by default the one ``create_app`` builds from ``settings``) the way
    the server runs in the field: the collector and allocator settled, uvicorn's
    WebSocket options, logs without tokens."""
    from server.api.ws_direct import uvicorn_ws_options
    from server.app import create_app

    if app is None:
        app = create_app(settings)
    _settle_gc()
    _settle_malloc(settings.ws_max_binary_bytes)
    uvicorn.run(
        app,
        host=settings.host,
        port=settings.port,
        log_level=settings.log_level,
        # no token in any line, text or JSON (server/logs.py)
        log_config=log_config(settings.log_level, settings.log_format),
        access_log=False,
        **uvicorn_ws_options(),
        # Open long polls (up to 30 s) must not hold a stop up: they are cut after this.
        timeout_graceful_shutdown=3,
    )


def _settle_gc() -> None:
    """Collector settings for a long-running server process.

    The code, schemas and routes loaded so far live as long as the process:
    ``gc.freeze`` takes them out of every later collection. A server holding
    thousands of sockets keeps hundreds of thousands of live objects, and
    CPython's default thresholds (700, 10, 10) scan the old ones again and
    again (measured at 5,000 vehicles: a full collection of ~0.4 s every few
    seconds, the bulk of the p99). A larger first threshold collects young
    garbage as before. The middle generation is collected after 5 young
    collections: what it scans is what survived them (stored buckets and
    their index entries, instance records written back), and a pass holds
    every socket for its length. Near a full core the acks queued behind a
    stall take several times its length to drain, so shorter passes, more
    often, make the p99: at 10,000 vehicles a pass took 170 to 240 ms every
    ~25 s after 50 young collections, 40 to 80 ms after 10, 20 to 50 ms
    after 5. The oldest generation keeps its pace (after 250 middle ones, and
    only once it has grown by a quarter).
    """
    gc.collect()
    gc.freeze()
    gc.set_threshold(10_000, 5, 250)


#: glibc's mallopt parameters (malloc.h).
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3


def _settle_malloc(largest_frame: int) -> None:
    """Keep the memory of large frames in the process between messages (glibc only).

    A relayed 64 KiB message lives in several buffers at once (the frame
    read, its text, the event encoded, the frame written). When they are
    freed, the heap's top is over glibc's trim threshold (128 KiB) and goes
    back to the system, and the next message faults the same pages in again:
    measured here, 12.5 page faults per 64 KiB hop against none for a bare
    relay. With the threshold at 64 MiB the pages stay, and frames up to the
    largest accepted come from the heap rather than a fresh ``mmap`` each.
    """
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return  # not glibc: its defaults stay
    mallopt(_M_TRIM_THRESHOLD, 64 << 20)
    mallopt(_M_MMAP_THRESHOLD, min(max(largest_frame * 2, 1 << 20), 32 << 20))  # glibc caps 32 MiB


def main() -> None:
    app()


if __name__ == "__main__":
    main()
