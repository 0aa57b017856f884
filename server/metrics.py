"""Prometheus metrics: requests, latencies, connected vehicles, commands by status, and
the delay of each hop a message takes (:class:`Hops`).

Each app has its own registry (tests build many apps in one process).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable

from prometheus_client import CollectorRegistry, Counter, Histogram
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
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


#: Buckets of the hop histograms: 1 ms to 10 s.
HOP_BUCKETS = (0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.5, 5.0, 10.0)
#: A hop measured longer than this (or negative by more) is a clock gone wrong, not a
#: delay: counted in ``fleet_hop_discarded``, not observed.
HOP_MAX_S = 60.0


class Hops:
    """The delay of each hop a message takes, measured by the server itself (docs/live.md,
    "Latency per hop"). Each ``observe`` is one histogram observation: a value below zero
    (clocks a little apart) is observed as 0 and counted in ``fleet_hop_clamped``; one
    beyond ``HOP_MAX_S`` either way is counted in ``fleet_hop_discarded`` and dropped.
    Never raises for a value."""

    def __init__(self, registry: CollectorRegistry) -> None:
        def histogram(name: str, doc: str, labels: tuple[str, ...] = ()) -> Histogram:
            return Histogram(name, doc, labels, buckets=HOP_BUCKETS, registry=registry)

        self.vehicle_to_server_h = histogram(
            "fleet_hop_vehicle_to_server_seconds",
            "vehicle to server: a telemetry call's send time (vehicle clock, corrected by the"
            " vehicle's estimate of the clock offset) to its arrival",
            ("transport",),
        )
        self.server_to_operator_h = histogram(
            "fleet_hop_server_to_operator_seconds",
            "server to operator: a live event's publication to its write on an operator's socket",
        )
        self.submitted_to_delivered_h = histogram(
            "fleet_command_submitted_to_delivered_seconds",
            "a command's submission to its first hand-out to the vehicle",
        )
        self.delivered_to_acked_h = histogram(
            "fleet_command_delivered_to_acked_seconds",
            "a command's hand-out to the vehicle's first ack of it",
        )
        self.submitted_to_acked_h = histogram(
            "fleet_command_submitted_to_acked_seconds",
            "a command's submission to the vehicle's first ack of it",
        )
        self.clamped = Counter(
            "fleet_hop_clamped",
            "hop delays measured below zero (clocks apart), observed as 0",
            ["hop"],
            registry=registry,
        )
        self.discarded = Counter(
            "fleet_hop_discarded",
            f"hop delays beyond {HOP_MAX_S:g} s either way (a clock gone wrong), not observed",
            ["hop"],
            registry=registry,
        )
        # The labelled children, bound once: an observation is one call.
        self._v2s = {t: self.vehicle_to_server_h.labels(t) for t in ("ws", "http")}

    def _observe(self, histogram: Histogram, hop: str, seconds: float) -> None:
        if 0.0 <= seconds <= HOP_MAX_S:
            histogram.observe(seconds)
        elif -HOP_MAX_S <= seconds < 0.0:
            histogram.observe(0.0)
            self.clamped.labels(hop).inc()
        else:  # beyond the bound, or NaN
            self.discarded.labels(hop).inc()

    def vehicle_to_server(self, transport: str, seconds: float) -> None:
        child = self._v2s.get(transport) or self.vehicle_to_server_h.labels(transport)
        self._observe(child, "vehicle_to_server", seconds)

    def server_to_operator(self, seconds: float) -> None:
        self._observe(self.server_to_operator_h, "server_to_operator", seconds)

    def command_delivered(self, submitted_s: float) -> None:
        """A command handed out for the first time, ``submitted_s`` after its submission."""
        self._observe(self.submitted_to_delivered_h, "submitted_to_delivered", submitted_s)

    def command_acked(self, delivered_s: float | None, submitted_s: float) -> None:
        """The vehicle's first ack of a command, after its hand-out and its submission."""
        if delivered_s is not None:
            self._observe(self.delivered_to_acked_h, "delivered_to_acked", delivered_s)
        self._observe(self.submitted_to_acked_h, "submitted_to_acked", submitted_s)


class Tally(Collector):
    """A counter for a hot path: ``add`` is a plain addition (a ``Counter`` takes a lock
    at every ``inc``: at 10,000 samples a second, 1 % of a core), read at each scrape.
    The event loop's thread is the only one that adds."""

    def __init__(self, name: str, doc: str) -> None:
        self.name, self.doc = name, doc
        self.total = 0

    def add(self, amount: int) -> None:
        self.total += amount

    def collect(self) -> Iterable[Metric]:
        yield CounterMetricFamily(self.name, self.doc, value=self.total)


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
        self.samples = Tally("fleet_samples_ingested", "telemetry samples accepted")
        self.registry.register(self.samples)
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
        self.hops = Hops(self.registry)

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
