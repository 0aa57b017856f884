"""``fleetctl`` run in the test's process against a server's URL, off the event loop, and
the server with a vehicle that most of its tests start from."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

import httpx
from typer.testing import CliRunner, Result

from remote_client.cli import app
from server.settings import Settings
from tests.factories import make_vehicle, start_instance
from tests.live import serve

runner = CliRunner()


async def fleetctl(base: str, token: str, *args: str, input: str | None = None) -> Result:
    """``fleetctl ARGS`` with ``FLEET_SERVER`` and ``FLEET_TOKEN`` set; stdout and stderr
    apart (``result.stdout``, ``result.stderr``)."""
    env = {"FLEET_SERVER": base, "FLEET_TOKEN": token}
    return await asyncio.to_thread(runner.invoke, app, list(args), env=env, input=input)


def token_of(headers: dict[str, str]) -> str:
    return headers["Authorization"].removeprefix("Bearer ")


@asynccontextmanager
async def served_vehicle(
    settings: Settings, name: str | None = None
) -> AsyncIterator[tuple[str, httpx.AsyncClient, str, dict[str, str], str]]:
    """A real server on ``settings``, a client to it, and a vehicle registered with its
    instance started (announcing ``name`` when given): ``(base URL, client, vehicle_id,
    the vehicle's auth header, instance_id)``."""
    async with serve(settings) as base, httpx.AsyncClient(base_url=base) as c:
        vid, vh = await make_vehicle(c)
        iid = (await start_instance(c, vid, vh, name=name))["instance_id"]
        yield base, c, vid, vh, iid
