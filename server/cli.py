"""``fleet-server``: run the cloud server. ``--help`` lists every FLEET_* setting."""

from __future__ import annotations

import gc
import logging
from typing import Any

import typer
import uvicorn

from server.settings import Settings


def _settings_help() -> str:
    lines = ["\b", "Settings come from FLEET_* environment variables (or a .env file):"]
    for name, field in Settings.model_fields.items():
        default: Any = field.default
        if default is None:
            default = "unset"
        lines.append(f"  FLEET_{name.upper():<27} {field.description} [default: {default}]")
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
    settings = Settings(**overrides)
    run(settings)


def run(settings: Settings) -> None:
    from server.app import create_app

    logging.basicConfig(
        level=settings.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    app = create_app(settings)
    _settle_gc()
    uvicorn.run(
        app,
        host=settings.host,
        port=settings.port,
        log_level=settings.log_level,
        access_log=False,
        ws_per_message_deflate=False,
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
    seconds, the bulk of the p99); larger thresholds collect young garbage
    as before, the old generations less often.
    """
    gc.collect()
    gc.freeze()
    gc.set_threshold(10_000, 50, 50)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
