"""What the server serves for the console and for ``/docs``: its own files, nothing from a
CDN, nothing of the npm folder but the two packages' assets; no token needed."""

from __future__ import annotations

from collections.abc import Callable

import httpx
import pytest
from asgi_lifespan import LifespanManager

from server.api.console import WEB_DIR
from server.app import create_app
from server.settings import Settings

MODULES = WEB_DIR / "node_modules"


@pytest.fixture
async def web(make_settings: Callable[..., Settings]) -> httpx.AsyncClient:
    if not (MODULES / "leaflet").is_dir():
        pytest.fail("server/web/node_modules is missing: run `make web` (npm ci in server/web)")
    app = create_app(make_settings(map_tile_url="http://tiles.example/{z}/{x}/{y}.png"))
    async with LifespanManager(app) as m:
        transport = httpx.ASGITransport(app=m.app)
        async with httpx.AsyncClient(transport=transport, base_url="http://t") as c:
            yield c


async def test_the_console_and_its_modules(web: httpx.AsyncClient) -> None:
    page = await web.get("/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert 'src="js/main.js"' in page.text and "/vendor/leaflet/leaflet.css" in page.text
    for path in ("/js/main.js", "/js/map.js", "/console.css"):
        assert (await web.get(path)).status_code == 200, path
    leaflet = await web.get("/vendor/leaflet/leaflet-src.esm.js")
    assert leaflet.status_code == 200 and "export" in leaflet.text


async def test_docs_take_swagger_ui_from_the_server(web: httpx.AsyncClient) -> None:
    docs = await web.get("/docs")
    assert docs.status_code == 200
    assert "/vendor/swagger-ui/swagger-ui-bundle.js" in docs.text
    assert "/vendor/swagger-ui/swagger-ui.css" in docs.text
    assert "http" not in docs.text.replace("/openapi.json", ""), "a URL outside the server"
    for asset in ("swagger-ui-bundle.js", "swagger-ui.css", "favicon-32x32.png"):
        assert (await web.get(f"/vendor/swagger-ui/{asset}")).status_code == 200
    assert (await web.get("/redoc")).status_code == 404  # it would load from a CDN


async def test_the_console_settings(web: httpx.AsyncClient) -> None:
    config = (await web.get("/console/config.json")).json()
    assert config == {"tile_url": "http://tiles.example/{z}/{x}/{y}.png", "tile_attribution": ""}


async def test_nothing_else_of_the_web_folder(web: httpx.AsyncClient) -> None:
    for path in (
        "/package.json",
        "/node_modules/leaflet/package.json",
        "/vendor/leaflet/../package.json",
    ):
        assert (await web.get(path)).status_code == 404, path


async def test_another_method_on_a_file_is_405_and_on_no_file_404(web: httpx.AsyncClient) -> None:
    """The console's files take GET and HEAD: another method is 405 where a file is (or
    the console's page), 404 where none is, as any path the server does not have."""
    for path in ("/", "/index.html", "/js/main.js", "/vendor/leaflet/leaflet.css"):
        r = await web.post(path)
        assert r.status_code == 405, path
        assert (
            r.headers["allow"] == "GET, HEAD" and r.json()["error"]["code"] == "method_not_allowed"
        )
        assert (await web.head(path)).status_code == 200, path
    for path in ("/nope", "/js/nope.js", "/vendor/leaflet/nope.js", "/vendor/nope"):
        r = await web.delete(path)
        assert r.status_code == 404, path
        assert r.json()["error"]["code"] == "not_found"


async def test_no_page_here_may_be_framed_and_the_console_runs_only_its_own_scripts(
    web: httpx.AsyncClient,
) -> None:
    for path in ("/", "/js/main.js", "/vendor/leaflet/leaflet.css", "/docs"):
        r = await web.get(path)
        assert r.headers["x-frame-options"] == "DENY", path
        assert r.headers["x-content-type-options"] == "nosniff", path
        assert "frame-ancestors 'none'" in r.headers["content-security-policy"], path
    policy = (await web.get("/")).headers["content-security-policy"]
    assert "script-src 'self';" in policy and "connect-src 'self'" in policy
    assert "script-src" not in (await web.get("/docs")).headers["content-security-policy"]


async def test_the_document_says_every_call_but_the_open_ones_takes_a_bearer_token(
    web: httpx.AsyncClient,
) -> None:
    """So Swagger UI offers Authorize and its Try it out sends the token."""
    doc = (await web.get("/openapi.json")).json()
    assert doc["components"]["securitySchemes"]["bearer"]["scheme"] == "bearer"
    assert doc["paths"]["/api/vehicles"]["get"]["security"] == [{"bearer": []}]
    assert doc["paths"]["/upper/update_param"]["post"]["security"] == [{"bearer": []}]
    assert doc["paths"]["/healthz"]["get"]["security"] == []
    assert doc["paths"]["/auth/token"]["post"]["security"] == []
