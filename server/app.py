"""The app factory: routers, error handlers, middleware and a lifespan that owns the services."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles

from fleet_protocol import utcnow
from server import container
from server.api import (
    admin,
    client,
    control,
    errors,
    fleet,
    fleet_telemetry,
    health,
    obstacles,
    upper,
    upper_control,
    ws,
)
from server.api.limits import BodyLimit
from server.metrics import Metrics, MetricsMiddleware
from server.settings import Settings
from server.storage import Store

WEB_DIR = Path(__file__).parent / "web"


def create_app(
    settings: Settings | None = None,
    *,
    clock: container.Clock = utcnow,
    store: Store | None = None,
) -> FastAPI:
    """The app. ``store``: an open store to use instead of the one the settings name; its
    opener loads and closes it (tests hand two apps one embedded store, as two replicas
    share one MongoDB)."""
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        services = await container.build(settings, metrics, clock, store)
        app.state.services = services
        if services.admin_token:
            # Shown once on the console for a new user; never logged.
            print(f"fleet-server: admin token (shown once): {services.admin_token}", flush=True)
        container.start_background(services)
        try:
            yield
        finally:
            await container.shutdown(services)

    app = FastAPI(
        title="fleet-cloud",
        version="0.1.0",
        summary="Monitor and command fleets of unmanned marine vehicles",
        lifespan=lifespan,
    )
    metrics = Metrics()  # not bound to a loop: built here so the middleware can hold it
    errors.install(app)
    # Vehicles call most often: their routes are matched first.
    for module in (upper, upper_control, client, control, fleet, health, admin, obstacles, ws):
        app.include_router(module.router)
    app.include_router(fleet_telemetry.router)
    if WEB_DIR.is_dir() and any(WEB_DIR.iterdir()):
        app.mount("/", StaticFiles(directory=WEB_DIR, html=True), name="web")
    app.add_middleware(MetricsMiddleware, metrics=metrics)
    app.add_middleware(BodyLimit, max_bytes=settings.max_body_bytes)
    return app
