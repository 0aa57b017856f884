"""Prometheus metrics: requests, latencies, connected vehicles, commands by status.

Each app has its own registry (tests build many apps in one process).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable

from prometheus_client import CollectorRegistry, Counter, Histogram
from prometheus_client.core import GaugeMetricFamily, Metric
from prometheus_client.registry import Collector
from starlette.types import ASGIApp, Message, Receive, Scope, Send


class _Live(Collector):
    def __init__(
        self, name: str, doc: str, label: str | None, read: Callable[[], dict[str, float]]
    ) -> None:
        self.name, self.doc, self.label, self.read = name, doc, label, read

    def collect(self) -> Iterable[Metric]:
        family = GaugeMetricFamily(self.name, self.doc, labels=[self.label] if self.label else [])
        for key, value in self.read().items():
            family.add_metric([key] if self.label else [], value)
        yield family


class Metrics:
    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        self.requests = Counter(
            "fleet_http_requests",
            "HTTP requests",
            ["method", "route", "status"],
            registry=self.registry,
        )
        self.latency = Histogram(
            "fleet_http_request_seconds",
            "HTTP request latency",
            ["route"],
            buckets=(0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 10, 30),
            registry=self.registry,
        )
        self.samples = Counter(
            "fleet_samples_ingested", "telemetry samples accepted", registry=self.registry
        )
        self.background_errors = Counter(
            "fleet_background_errors",
            "records a background loop failed on (set aside), and passes it could not finish",
            ["loop"],
            registry=self.registry,
        )
        self.handler_errors = Counter(
            "fleet_event_handler_errors",
            "handlers of the server's internal events that failed",
            ["event"],
            registry=self.registry,
        )

    def background_error(self, loop: str) -> None:
        self.background_errors.labels(loop).inc()

    def handler_error(self, event: str) -> None:
        self.handler_errors.labels(event).inc()

    def live_gauge(
        self, name: str, doc: str, read: Callable[[], dict[str, float]], label: str | None = None
    ) -> None:
        self.registry.register(_Live(name, doc, label, read))


class MetricsMiddleware:
    def __init__(self, app: ASGIApp, metrics: Metrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start = time.perf_counter()
        status = 500

        async def record(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, record)
        finally:
            route = scope.get("route")
            path = getattr(route, "path", "unmatched")
            self.metrics.requests.labels(scope["method"], path, str(status)).inc()
            self.metrics.latency.labels(path).observe(time.perf_counter() - start)
