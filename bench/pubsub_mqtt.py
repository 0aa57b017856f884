"""Baseline for the live path: one-hop pub-sub latency through a Mosquitto broker.

Starts ``mosquitto`` on a free loopback port with a temporary config
(``set_tcp_nodelay``, no persistence), connects a publisher and a subscriber
(paho-mqtt, QoS 0, ``TCP_NODELAY`` on both sockets, both driven from one
thread), and publishes messages one at a time, each stamped with
``perf_counter_ns``: the latency of a message is the time from ``publish``
to its arrival in the subscriber's callback, the same clock on both ends.
One message in flight at a time, so this measures the hop, not a queue.

The main bench calls :func:`measure_mosquitto` for the baseline and
:func:`compare` with its own :class:`LatencyResult` for the server's
``/ws/client`` path (built with :meth:`LatencyResult.from_samples`).

Run alone: ``python -m bench.pubsub_mqtt [--count N] [--json]``.
Needs the ``mosquitto`` binary (Debian package ``mosquitto``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import statistics
import tempfile
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import paho.mqtt.client as mqtt

from bench._mosquitto import MqttPump, mosquitto
from bench._stats import percentile

__all__ = [
    "SIZES",
    "LatencyResult",
    "compare",
    "measure_mosquitto",
    "mosquitto_broker",
    "mqtt_one_hop",
]

SIZES = (100, 64 * 1024)
STAMP_BYTES = 8
TIMEOUT_S = 10.0


@dataclass(frozen=True)
class LatencyResult:
    path: str
    size: int
    count: int
    median_ms: float
    p99_ms: float
    mean_ms: float
    max_ms: float

    @classmethod
    def from_samples(cls, path: str, size: int, samples_ns: Sequence[int]) -> LatencyResult:
        ordered = sorted(samples_ns)
        if not ordered:
            raise ValueError("no samples")
        return cls(
            path=path,
            size=size,
            count=len(ordered),
            median_ms=statistics.median(ordered) / 1e6,
            p99_ms=percentile(ordered, 0.99) / 1e6,
            mean_ms=statistics.fmean(ordered) / 1e6,
            max_ms=ordered[-1] / 1e6,
        )


def compare(candidate: LatencyResult, baseline: LatencyResult) -> dict[str, float | str | int]:
    """Ratios of a candidate path to the baseline (the issue's goals: ≤ 1.25 and ≤ 1.5)."""
    return {
        "size": candidate.size,
        "candidate": candidate.path,
        "baseline": baseline.path,
        "median_ratio": candidate.median_ms / baseline.median_ms,
        "p99_ratio": candidate.p99_ms / baseline.p99_ms,
    }


@contextlib.contextmanager
def mosquitto_broker(binary: str | None = None) -> Iterator[int]:
    """A mosquitto broker on a free loopback port, for the duration; yields the port."""
    with (
        tempfile.TemporaryDirectory(prefix="bench-mosquitto-") as tmp,
        mosquitto(Path(tmp), binary=binary) as port,
    ):
        yield port


def mqtt_one_hop(port: int, size: int, count: int = 2000, warmup: int = 200) -> LatencyResult:
    """Latency of ``count`` messages of ``size`` bytes, one in flight at a time, QoS 0."""
    if size < STAMP_BYTES:
        raise ValueError(f"size is at least {STAMP_BYTES} bytes (the time stamp)")
    topic = f"bench/hop/{size}"
    arrived = threading.Event()
    latency_ns: list[int] = []

    def on_message(client: mqtt.Client, userdata: object, message: mqtt.MQTTMessage) -> None:
        now = time.perf_counter_ns()
        latency_ns.append(now - int.from_bytes(message.payload[:STAMP_BYTES], "big"))
        arrived.set()

    pump = MqttPump()
    try:
        subscriber = pump.connect(port, f"bench-sub-{size}")
        publisher = pump.connect(port, f"bench-pub-{size}")
        subscriber.on_message = on_message
        pump.subscribe(subscriber, topic)
        padding = bytes(size - STAMP_BYTES)
        for _ in range(warmup + count):
            arrived.clear()
            stamp = time.perf_counter_ns().to_bytes(STAMP_BYTES, "big")
            publisher.publish(topic, stamp + padding, qos=0)
            pump.until(arrived.is_set, "a message did not arrive within the timeout", TIMEOUT_S)
    finally:
        pump.close()
    return LatencyResult.from_samples("mosquitto-qos0", size, latency_ns[warmup:])


def measure_mosquitto(
    sizes: Sequence[int] = SIZES, count: int = 2000, warmup: int = 200
) -> dict[int, LatencyResult]:
    """Start a broker, measure each size, stop it: ``{size: result}``."""
    with mosquitto_broker() as port:
        return {size: mqtt_one_hop(port, size, count, warmup) for size in sizes}


def _table(results: Sequence[LatencyResult]) -> str:
    lines = [f"{'path':<16} {'size':>7} {'count':>6} {'median ms':>10} {'p99 ms':>8} {'max ms':>8}"]
    for r in results:
        lines.append(
            f"{r.path:<16} {r.size:>7} {r.count:>6} {r.median_ms:>10.3f} {r.p99_ms:>8.3f}"
            f" {r.max_ms:>8.3f}"
        )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=2000, help="messages per size")
    parser.add_argument("--warmup", type=int, default=200, help="messages not counted")
    parser.add_argument("--json", action="store_true", help="print JSON for scripts")
    args = parser.parse_args(argv)
    results = list(measure_mosquitto(count=args.count, warmup=args.warmup).values())
    if args.json:
        print(json.dumps([asdict(r) for r in results], indent=2))
    else:
        print(_table(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
