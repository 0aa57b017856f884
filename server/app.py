"""The app factory: routers, error handlers, middleware and a lifespan that owns the server."""

from __future__ import annotations

import inspect
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import TYPE_CHECKING, Any

from fastapi import APIRouter, FastAPI
from fastapi.routing import APIRoute

from fleet_protocol import utcnow
from server import container, running
from server.api import (
    admin,
    client,
    console,
    control,
    errors,
    fleet,
    fleet_telemetry,
    health,
    obstacles,
    safety,
    upper,
    upper_control,
    zones,
)
from server.api.durable import DurableAnswers
from server.api.limits import BodyLimit
from server.api.openapi import document_errors
from server.api.ws import LIVE_PATHS, serve_live
from server.metrics import Metrics, MetricsMiddleware
from server.settings import Settings
from server.storage import Store

if TYPE_CHECKING:
    from starlette.types import Receive, Scope, Send


class FleetApp(FastAPI):
    """The FastAPI app, with the live sockets (``/ws/vehicle``, ``/ws/client``) served
    straight from the ASGI call: see :mod:`server.api.ws` for why."""

    def openapi(self) -> dict[str, Any]:
        """FastAPI's document, with every error answer a route may give (``api/openapi``)."""
        if not self.openapi_schema:
            self.openapi_schema = document_errors(super().openapi())
        return self.openapi_schema

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "websocket":
            if scope["path"] not in LIVE_PATHS:
                await errors.no_socket_here(scope, send, list(LIVE_PATHS))
                return
            scope["app"] = self
            await serve_live(self.state.services, self.state.hub, scope, receive, send)
            return
        if scope["type"] == "http" and scope["method"] == "HEAD":
            # HEAD wherever GET (monitors probe /healthz so): answered as the GET, whose
            # body the server does not write for a HEAD (its own scope says HEAD).
            scope = {**scope, "method": "GET", errors.HEAD_SCOPE_KEY: True}
        await super().__call__(scope, receive, send)


#: The calls each vehicle makes every second or more: matched before the other routes.
_HOT_PATHS = ("/upper/update_param", "/upper/get_control")


def _flat(app: FastAPI, *routers: APIRouter) -> None:
    """The routers' routes made again as routes of the app itself, as if declared on it,
    those of ``_HOT_PATHS`` first (a request is matched against the routes in order;
    these paths are no other route's, so the order changes nothing else).

    ``include_router`` keeps a router as one entry that matches a request against
    its routes twice (once to choose the router, once the route) and walks them
    for a version stamp each time: tens of microseconds a call, paid by every
    vehicle's every call. Each route is declared again on the app with everything
    it was declared with (``add_api_route``'s parameters, its class), so the app
    serves and documents it the same, and dependency overrides reach it.
    """
    names = inspect.signature(APIRouter.add_api_route).parameters.keys()
    routes = [route for router in routers for route in router.routes]
    routes.sort(key=lambda route: getattr(route, "path", "") not in _HOT_PATHS)  # stable
    for route in routes:
        assert isinstance(route, APIRoute), route
        declared = {
            n: getattr(route, n) for n in names if n not in ("self", "route_class_override")
        }
        app.router.add_api_route(route_class_override=type(route), **declared)


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
        runtime = await container.build(settings, metrics, clock, store)
        app.state.runtime = runtime
        app.state.services = runtime.services
        app.state.hub = runtime.hub
        app.state.metrics = metrics
        await running.start(runtime)
        try:
            yield
        finally:
            await running.shutdown(runtime)

    app = FleetApp(
        title="fleet-cloud",
        version="0.1.0",
        summary="Monitor and command fleets of unmanned marine vehicles",
        lifespan=lifespan,
        docs_url=None,  # served by console.install from the server's own files (no CDN)
        redoc_url=None,
    )
    metrics = Metrics()  # not bound to a loop: built here so the middleware can hold it
    errors.install(app)
    # Vehicles call most often: their routes are matched first, and flat (see _flat).
    _flat(app, upper.router, upper_control.router)
    for module in (
        client,
        control,
        fleet,
        health,
        admin,
        obstacles,
        zones,
        safety,
    ):
        app.include_router(module.router)
    app.include_router(fleet_telemetry.router)
    console.install(app, settings)
    app.add_middleware(DurableAnswers)
    app.add_middleware(MetricsMiddleware, metrics=metrics)
    app.add_middleware(BodyLimit, max_bytes=settings.max_body_bytes)
    return app
