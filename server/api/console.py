"""The console's files (``/``), the assets it and Swagger UI take from npm (``/vendor/``),
Swagger UI at ``/docs`` and the console's settings (``/console/config.json``).

Nothing here reaches outside the server: Leaflet and swagger-ui-dist are installed by
``npm ci`` in ``server/web`` (``make web``) and served from there, so the console and
``/docs`` work on a laptop with no internet. These routes need no token (the files hold
no data; every call the console makes for data carries the user's token) and are left
out of the OpenAPI document.

Every page and file here says it may not be framed by another site (a click on Stop or
Grant in a hidden frame) nor sniffed as another type; the console's pages also carry a
Content-Security-Policy that runs only the server's own scripts and talks only to the
server, so a name a vehicle chose can never run as script even if a label forgot to
escape it. ``/docs`` keeps Swagger UI's inline start-up script: framing is all it forbids.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

from fastapi import APIRouter, FastAPI
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException
from starlette.responses import Response
from starlette.routing import BaseRoute, Match, Mount
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from server.settings import Settings

log = logging.getLogger("fleet.server")

WEB_DIR = Path(__file__).resolve().parent.parent / "web"
CONSOLE_DIR = WEB_DIR / "console"
#: URL prefix -> the folder of an npm package it serves (under node_modules).
VENDOR = {"/vendor/leaflet": "leaflet/dist", "/vendor/swagger-ui": "swagger-ui-dist"}

#: On every file and page served here (with a policy of frames, below).
_FRAMING: list[tuple[bytes, bytes]] = [
    (b"x-frame-options", b"DENY"),
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"no-referrer"),
]
#: The console's own scripts only; styles inline too (Leaflet's, the labels'); map tiles
#: from wherever ``FLEET_MAP_TILE_URL`` points; calls and sockets to this server alone.
CONSOLE_POLICY = (
    "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
    "img-src * data: blob:; connect-src 'self'; object-src 'none'; base-uri 'none'; "
    "form-action 'self'; frame-ancestors 'none'"
)
_CONSOLE_HEADERS = [*_FRAMING, (b"content-security-policy", CONSOLE_POLICY.encode())]
#: ``/docs`` and the npm assets: never framed, Swagger UI's inline script left to run.
_DOCS_HEADERS = [*_FRAMING, (b"content-security-policy", b"frame-ancestors 'none'")]


def vendor_dir(settings: Settings) -> Path:
    return settings.web_vendor_dir or WEB_DIR / "node_modules"


def console_config(settings: Settings) -> dict[str, str | None]:
    """What the console reads before it draws the map."""
    return {
        "tile_url": settings.map_tile_url,
        "tile_attribution": settings.map_tile_attribution,
    }


def router(settings: Settings, openapi_url: str) -> APIRouter:
    routes = APIRouter(include_in_schema=False)

    @routes.get("/docs")
    async def swagger_ui() -> HTMLResponse:
        page = get_swagger_ui_html(
            openapi_url=openapi_url,
            title="fleet-cloud API",
            swagger_js_url="/vendor/swagger-ui/swagger-ui-bundle.js",
            swagger_css_url="/vendor/swagger-ui/swagger-ui.css",
            swagger_favicon_url="/vendor/swagger-ui/favicon-32x32.png",
        )
        page.raw_headers.extend(_DOCS_HEADERS)
        return page

    @routes.get("/console/config.json")
    async def config() -> dict[str, str | None]:
        return console_config(settings)

    return routes


def install(app: FastAPI, settings: Settings) -> None:
    """Swagger UI and the console's routes, then the static files (mounted last: ``/``
    takes whatever no route took)."""
    app.include_router(router(settings, app.openapi_url or "/openapi.json"))
    modules = vendor_dir(settings)
    missing = [p for p in VENDOR.values() if not (modules / p).is_dir()]
    if missing:
        log.warning(
            "console assets missing in %s (%s): run `npm ci` in server/web (make web); "
            "until then the console's map and /docs cannot load",
            modules,
            ", ".join(missing),
        )
    for prefix, package in VENDOR.items():
        if (modules / package).is_dir():
            app.mount(prefix, _Headed(_Files(directory=modules / package), _DOCS_HEADERS))
    if CONSOLE_DIR.is_dir():
        files = _Files(directory=CONSOLE_DIR, html=True)
        app.router.routes.append(_Console(app.router.routes, _Headed(files, _CONSOLE_HEADERS)))


class _Files(StaticFiles):
    """Static files, of which a path that is none is 404 whatever the method: asked with
    another method than GET or HEAD, a file there is 405 (``Allow: GET, HEAD``), a path
    with no file 404 (Starlette's answer 405 to any path: ``POST /api/nonexistent`` read
    as a call the API had)."""

    async def get_response(self, path: str, scope: Scope) -> Response:
        if scope["method"] in ("GET", "HEAD"):
            return await super().get_response(path, scope)
        found = await super().get_response(path, {**scope, "method": "HEAD"})  # 404: raised
        if found.status_code == 404:  # a 404.html page
            raise HTTPException(status_code=404)
        raise HTTPException(
            405,
            f"{scope['method']} is not allowed here; a file takes GET, HEAD",
            {"Allow": "GET, HEAD"},
        )


class _Headed:
    """Static files with ``headers`` added to each answer."""

    def __init__(self, app: ASGIApp, headers: list[tuple[bytes, bytes]]) -> None:
        self.app = app
        self.headers = headers

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        async def send_headed(message: Message) -> None:
            if message["type"] == "http.response.start":
                message = {**message, "headers": [*message.get("headers", ()), *self.headers]}
            await send(message)

        await self.app(scope, receive, send_headed)


class _Console(Mount):
    """``/``: the console's files, for the paths no route of the app has. A path a route
    has, asked with a method it does not take (``GET /upper/heartbeat``), stays that
    route's: 405, not the 404 of a missing file."""

    def __init__(self, routes: Sequence[BaseRoute], files: ASGIApp) -> None:
        super().__init__("/", app=files, name="web")
        self._routes = routes

    def matches(self, scope: Scope) -> tuple[Match, Scope]:
        if scope["type"] == "http" and any(
            route is not self and route.matches(scope)[0] is Match.PARTIAL for route in self._routes
        ):
            return Match.NONE, {}
        return super().matches(scope)
