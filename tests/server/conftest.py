"""Fixtures of the end-to-end socket tests: a real uvicorn serving the app, and an HTTP
client to it (a module may override ``base`` with settings of its own)."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable

import httpx
import pytest

from server.settings import Settings
from tests.live import serve


@pytest.fixture
async def base(make_settings: Callable[..., Settings]) -> AsyncIterator[str]:
    async with serve(make_settings()) as url:
        yield url


@pytest.fixture
async def api(base: str) -> AsyncIterator[httpx.AsyncClient]:
    async with httpx.AsyncClient(base_url=base, timeout=10) as c:
        yield c
