"""Shared fixtures: an app on a fresh embedded store, an HTTP client to it.

``tests/stores.py`` adds the store servers: ``ferretdb``, ``make_ferretdb``, ``mongo_url``
and ``store_backend``; a module that takes ``store_backend`` (``pytestmark =
pytest.mark.usefixtures("store_backend")``) runs each test on the embedded store and on
FerretDB (or ``FLEET_TEST_MONGO_URL``), ``make_settings`` choosing the store.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import httpx
import pytest
from asgi_lifespan import LifespanManager

from server.app import create_app
from server.settings import Settings
from tests.factories import ADMIN_TOKEN, FakeClock

if TYPE_CHECKING:
    from tests.stores import StoreBackend

# The store servers' fixtures and the per-backend summary (imported here first, as a
# plugin, so that pytest rewrites its asserts).
pytest_plugins = ["tests.stores"]


@pytest.fixture
def make_settings(tmp_path: Path, request: pytest.FixtureRequest) -> Callable[..., Settings]:
    """Settings for a test's app; on the test's ``store_backend`` when it takes one."""
    backend: StoreBackend | None = None
    if "store_backend" in request.fixturenames:
        backend = request.getfixturevalue("store_backend")

    def build(**overrides: Any) -> Settings:
        values: dict[str, Any] = {
            "snapshot_path": tmp_path / "store.snapshot",
            "admin_token": ADMIN_TOKEN,
            "rate_limit_per_s": 100_000,
            "rate_limit_burst": 100_000,
        }
        if backend is not None:
            values.update(backend.settings)
        values.update(overrides)
        return Settings(_env_file=None, **values)

    return build


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock()


@pytest.fixture
async def client(make_settings: Callable[..., Settings]) -> AsyncIterator[httpx.AsyncClient]:
    """A client to an app with the real clock."""
    app = create_app(make_settings())
    async with LifespanManager(app) as manager:
        transport = httpx.ASGITransport(app=manager.app)
        async with httpx.AsyncClient(transport=transport, base_url="http://test") as c:
            yield c


@pytest.fixture
async def clocked_client(
    make_settings: Callable[..., Settings], clock: FakeClock
) -> AsyncIterator[httpx.AsyncClient]:
    """A client to an app whose clock the test moves (``clock.advance``)."""
    app = create_app(make_settings(), clock=clock)
    async with LifespanManager(app) as manager:
        transport = httpx.ASGITransport(app=manager.app)
        async with httpx.AsyncClient(transport=transport, base_url="http://test") as c:
            yield c
