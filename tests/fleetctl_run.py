"""``fleetctl`` run in the test's process against a server's URL, off the event loop."""

from __future__ import annotations

import asyncio

from typer.testing import CliRunner, Result

from remote_client.cli import app

runner = CliRunner()


async def fleetctl(base: str, token: str, *args: str, input: str | None = None) -> Result:
    """``fleetctl ARGS`` with ``FLEET_SERVER`` and ``FLEET_TOKEN`` set; stdout and stderr
    apart (``result.stdout``, ``result.stderr``)."""
    env = {"FLEET_SERVER": base, "FLEET_TOKEN": token}
    return await asyncio.to_thread(runner.invoke, app, list(args), env=env, input=input)


def token_of(headers: dict[str, str]) -> str:
    return headers["Authorization"].removeprefix("Bearer ")
