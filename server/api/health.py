"""Liveness, readiness and metrics: no auth."""

from __future__ import annotations

from fastapi import APIRouter, Response
from fastapi.responses import JSONResponse
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from server.api.deps import ServicesDep

router = APIRouter(tags=["health"])


@router.get("/healthz")
async def healthz() -> dict[str, str]:
    return {"status": "ok"}


@router.get("/readyz")
async def readyz(services: ServicesDep) -> JSONResponse:
    checks = {"store": await services.store.ping()}
    if services.bus.remote:
        checks["redis"] = services.bus.healthy
    ready = all(checks.values())
    body = {
        "ready": ready,
        "checks": checks,
        "store": "embedded" if services.store.embedded else "mongodb",
    }
    if ready:
        return JSONResponse(body)
    return JSONResponse(
        {
            **body,
            "error": {
                "code": "unavailable",
                "message": "not ready: "
                + ", ".join(k for k, v in checks.items() if not v)
                + " unreachable",
                "details": checks,
            },
        },
        status_code=503,
        headers={"Retry-After": "2"},
    )


@router.get("/metrics")
async def metrics(services: ServicesDep) -> Response:
    return Response(generate_latest(services.metrics.registry), media_type=CONTENT_TYPE_LATEST)
