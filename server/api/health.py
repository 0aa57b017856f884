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
    """Ready: the store answers and the start-up work is done. Redis (when set) gone is
    ``degraded``, still 200: this replica serves its own sockets, only other replicas'
    subscribers miss what happens here until it is back."""
    store_problem = await services.store.ping()
    if store_problem is None and not services.readiness.loaded:
        store_problem = services.readiness.reason
    checks = {"store": store_problem is None}
    reasons = {"store": store_problem} if store_problem else {}
    if services.bus.remote:
        checks["redis"] = services.bus.healthy
        if not services.bus.healthy:
            reasons["redis"] = "Redis unreachable: other replicas are not told"
    ready = checks["store"]
    status = "unavailable" if not ready else "degraded" if reasons else "ok"
    body: dict[str, object] = {
        "ready": ready,
        "status": status,
        "checks": checks,
        "store": services.store.kind,
        "durability": services.store.durability,
    }
    if reasons:
        body["reasons"] = reasons
    if ready:
        return JSONResponse(body)
    return JSONResponse(
        {
            **body,
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
