"""Health, metrics, and the store (embedded, and FerretDB through the real driver)
surviving a restart; an unreachable MongoDB."""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Callable

import httpx
import pytest
from asgi_lifespan import LifespanManager

from server.app import create_app
from server.settings import Settings
from tests.factories import ADMIN, make_vehicle, sample, start_instance


async def test_healthz_readyz_metrics_need_no_token(client: httpx.AsyncClient) -> None:
    assert (await client.get("/healthz")).json() == {"status": "ok"}
    ready = (await client.get("/readyz")).json()
    assert ready["ready"] is True and ready["store"] == "embedded"
    await client.get("/api/vehicles", headers=ADMIN)
    text = (await client.get("/metrics")).text
    assert 'fleet_http_requests_total{method="GET",route="/api/vehicles",status="200"}' in text
    assert "fleet_vehicles" in text


def _app_client(app: object) -> httpx.AsyncClient:
    return httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://t")  # type: ignore[arg-type]


@pytest.mark.usefixtures("store_backend")
async def test_the_store_survives_a_clean_restart(
    make_settings: Callable[..., Settings],
) -> None:
    settings = make_settings()
    app = create_app(settings)
    async with LifespanManager(app) as m, _app_client(m.app) as c:
        vid, vh = await make_vehicle(c)
        iid = (await start_instance(c, vid, vh))["instance_id"]
        r = await c.post(
            "/upper/update_param",
            headers=vh,
            json={"instance_id": iid, "params": {"mode": "survey"}, "samples": [sample(1)]},
        )
        await app.state.services.instances.sweep(everything=True)  # params: the whole record
        r = await c.post(  # then contact and position alone move (written by the shutdown)
            "/upper/update_param",
            headers=vh,
            json={"instance_id": iid, "samples": [sample(i) for i in range(2, 51)]},
        )
        assert r.json()["acked_through_seq"] == 50
    app = create_app(settings)
    async with LifespanManager(app) as m, _app_client(m.app) as c:
        again = await start_instance(c, vid, vh)  # the vehicle's token survived too
        assert again["resumed"] is True and again["instance_id"] == iid
        assert again["last_seq"] == 50
        params = (
            await c.get("/client/get_param", headers=ADMIN, params={"instance_id": iid})
        ).json()
        assert params["position"]["seq"] == 50  # written through the keyed path, replayed
        assert params["params"] == {"mode": "survey"}  # not lost to the contact-only write
        page = (
            await c.get(
                f"/api/vehicles/{vid}/telemetry",
                headers=ADMIN,
                params={"after_seq": 0, "limit": 100},
            )
        ).json()
        assert [s["seq"] for s in page["samples"]] == list(range(1, 51))


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


async def test_unreachable_mongodb_is_503_not_a_hang(
    make_settings: Callable[..., Settings],
) -> None:
    url = f"mongodb://127.0.0.1:{_closed_port()}/?directConnection=true"
    app = create_app(make_settings(mongo_url=url, store_timeout_ms=300))
    # Deadlines guard against a hang; the store's own timeout answers well within them.
    async with LifespanManager(app, startup_timeout=30) as m, _app_client(m.app) as c:
        r = await asyncio.wait_for(c.get("/readyz"), 30)
        assert r.status_code == 503
        assert r.json()["ready"] is False and r.headers["Retry-After"]
        r = await asyncio.wait_for(c.get("/api/vehicles", headers=ADMIN), 30)
        assert r.status_code == 503
        assert r.json()["error"]["code"] == "unavailable" and r.headers["Retry-After"]
