"""Liveness, readiness and metrics: no auth."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response
from fastapi.responses import JSONResponse
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from server.api.deps import ServicesDep
from server.metrics import Metrics

router = APIRouter(tags=["health"])


@router.get("/healthz")
async def healthz() -> dict[str, str]:
    return {"status": "ok"}


@router.get("/readyz")
async def readyz(services: ServicesDep) -> JSONResponse:
    """Ready: the store answers and the start-up work is done (and Redis, when set)."""
    store_problem = await services.store.ping()
    if store_problem is None and not services.readiness.loaded:
        store_problem = services.readiness.reason
    checks = {"store": store_problem is None}
    reasons = {"store": store_problem} if store_problem else {}
    if services.bus.remote:
        checks["redis"] = services.bus.healthy
        if not services.bus.healthy:
            reasons["redis"] = "Redis unreachable: other replicas are not told"
    ready = all(checks.values())
    body = {
        "ready": ready,
        "checks": checks,
        "store": services.store.kind,
        "durability": services.store.durability,
    }
    if ready:
        return JSONResponse(body)
    return JSONResponse(
        {
            **body,
            "reasons": reasons,
            "error": {
                "code": "unavailable",
                "message": "not ready: " + "; ".join(reasons.values()),
                "details": checks,
            },
        },
        status_code=503,
        headers={"Retry-After": "2"},
    )


@router.get("/metrics")
async def metrics(request: Request) -> Response:
    registry: Metrics = request.app.state.metrics
    return Response(generate_latest(registry.registry), media_type=CONTENT_TYPE_LATEST)
