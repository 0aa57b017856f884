"""The server for the HTTP bench, in its own process: ``python -m bench._serve PORT DIR TOKEN``.

The real app (embedded store in DIR) plus two hidden routes served by the same
process: ``GET /_bench/trivial`` (the baseline) and ``POST /_bench/parse_only``
(update_param's body read and answered, nothing done). It runs as
``fleet-server`` does (``server.cli.run``: uvicorn, the collector and allocator
settings, no access log).
"""

from __future__ import annotations

import sys
from pathlib import Path

from fleet_protocol import UpdateParam, UpdateParamResult
from server.app import create_app
from server.cli import run
from server.settings import Settings


def main() -> None:
    port, directory, token = int(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
    settings = Settings(
        _env_file=None,
        snapshot_path=directory / "bench.snapshot",
        admin_token=token,
        rate_limit_per_s=1e9,
        rate_limit_burst=10**9,
        port=port,
        log_level="warning",
    )
    app = create_app(settings)

    async def trivial() -> dict[str, bool]:
        return {"ok": True}

    async def parse_only(body: UpdateParam) -> UpdateParamResult:
        """The floor: update_param's body parsed and an answer written, nothing done."""
        return UpdateParamResult(
            accepted=len(body.samples), duplicates=0, acked_through_seq=0, durable_through_seq=0
        )

    app.add_api_route("/_bench/trivial", trivial, methods=["GET"], include_in_schema=False)
    app.router.routes.insert(0, app.router.routes.pop())  # before the dashboard's "/" mount
    app.add_api_route("/_bench/parse_only", parse_only, methods=["POST"], include_in_schema=False)
    app.router.routes.insert(0, app.router.routes.pop())
    run(settings, app)  # as ``fleet-server`` runs it: the same process settings


if __name__ == "__main__":
    main()
