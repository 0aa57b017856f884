"""Fixtures of the agent's tests: ``harbour``, the server in process that the safety tests'
boats sail in (``harbour.py``)."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable
from pathlib import Path

import pytest

from server.settings import Settings
from tests.agent.harbour import Harbour, in_process


@pytest.fixture
async def harbour(make_settings: Callable[..., Settings], tmp_path: Path) -> AsyncIterator[Harbour]:
    settings = make_settings(
        separation_m=10.0, forecast_s=60.0, forecast_every_s=0.2, heartbeat_interval_s=0.5
    )
    async with in_process(settings) as (app, http):
        h = Harbour(app, http, tmp_path)
        try:
            yield h
        finally:
            for task in h.tasks:
                task.cancel()
            for task in h.tasks:
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await task
            for boat in h.boats:
                boat.agent.outbox.close()
