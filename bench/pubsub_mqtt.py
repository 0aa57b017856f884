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
import select
import shutil
import socket
import statistics
import subprocess
import tempfile
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import paho.mqtt.client as mqtt

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
        p99_index = min(len(ordered) - 1, max(0, round(0.99 * len(ordered)) - 1))
        return cls(
            path=path,
            size=size,
            count=len(ordered),
            median_ms=statistics.median(ordered) / 1e6,
            p99_ms=ordered[p99_index] / 1e6,
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


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@contextlib.contextmanager
def mosquitto_broker(binary: str | None = None) -> Iterator[int]:
    """A mosquitto broker on a free loopback port, for the duration; yields the port."""
    binary = binary or shutil.which("mosquitto") or "/usr/sbin/mosquitto"
    if not Path(binary).exists():
        raise RuntimeError("mosquitto is not installed (apt-get install mosquitto)")
    with tempfile.TemporaryDirectory(prefix="bench-mosquitto-") as tmp:
        port = _free_port()
        config = Path(tmp) / "mosquitto.conf"
        config.write_text(
            f"listener {port} 127.0.0.1\n"
            "allow_anonymous true\n"
            "persistence false\n"
            "set_tcp_nodelay true\n"
            "max_packet_size 1048576\n"
            "log_dest none\n"
        )
        process = subprocess.Popen(
            [binary, "-c", str(config)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
        )
        try:
            _wait_for_port(port, process)
            yield port
        finally:
            process.terminate()
            try:
                process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def _wait_for_port(port: int, process: subprocess.Popen[bytes]) -> None:
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        if process.poll() is not None:
            error = process.stderr.read().decode() if process.stderr else ""
            raise RuntimeError(f"mosquitto exited: {error.strip()}")
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 0.2):
            return
        time.sleep(0.02)
    raise RuntimeError(f"mosquitto did not listen on {port} within {TIMEOUT_S}s")


class _Pump:
    """Drives paho clients from this thread (no loop threads): ``select`` on their sockets.

    One thread for both ends, as the server's bench clients are: the figures
    then hold no thread switching of the measuring side.
    """

    def __init__(self) -> None:
        self.clients: list[mqtt.Client] = []

    def connect(self, port: int, name: str) -> mqtt.Client:
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=name)
        connected = threading.Event()
        client.on_connect = lambda *args: connected.set()
        client.connect("127.0.0.1", port)
        sock = client.socket()
        assert isinstance(sock, socket.socket)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.clients.append(client)
        self.until(connected, f"{name} could not connect to mosquitto on {port}")
        return client

    def until(self, event: threading.Event, failure: str) -> None:
        """Read and write the clients' sockets until ``event`` is set."""
        deadline = time.monotonic() + TIMEOUT_S
        while not event.is_set():
            if time.monotonic() > deadline:
                raise RuntimeError(failure)
            for client in self.clients:
                if client.want_write():
                    client.loop_write()
            sockets = {c.socket(): c for c in self.clients if c.socket() is not None}
            readable, _, _ = select.select(list(sockets), [], [], 0.05)  # type: ignore[type-var]
            for sock in readable:
                sockets[sock].loop_read()
            for client in self.clients:
                client.loop_misc()

    def close(self) -> None:
        for client in self.clients:
            client.disconnect()
            if client.want_write():
                client.loop_write()


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

    pump = _Pump()
    try:
        subscriber = pump.connect(port, f"bench-sub-{size}")
        publisher = pump.connect(port, f"bench-pub-{size}")
        subscribed = threading.Event()
        subscriber.on_message = on_message
        subscriber.on_subscribe = lambda *args: subscribed.set()
        subscriber.subscribe(topic, qos=0)
        pump.until(subscribed, "mosquitto did not confirm the subscription")
        padding = bytes(size - STAMP_BYTES)
        for _ in range(warmup + count):
            arrived.clear()
            stamp = time.perf_counter_ns().to_bytes(STAMP_BYTES, "big")
            publisher.publish(topic, stamp + padding, qos=0)
            pump.until(arrived, "a message did not arrive within the timeout")
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
