"""The seed papers' WAN figures, replayed through a 29 ms round trip (issue 15).

A real fleet-server (``python -m server.cli``, embedded store, rate limits out of
the way) and, in front of it, ``bench._faults.FaultProxy`` with a one-way delay
of 14.5 ms each way: the cloud-based paper's 29 ms round trip. The proxy runs in
its own process (``python -m bench.wan proxy UPSTREAM_PORT ONE_WAY_S``), so its timers and
the bench's clients do not share an interpreter lock.

(a) **Table 2.** Each seed method, one call at a time over keep-alive
    connections through the proxy with ``httpx`` (an operator's client and a
    vehicle's, as the paper's clients called its cloud server): ``connect_instance``
    (by vehicle id), ``get_param`` (every parameter and the position),
    ``submit_control`` (one ``go_to`` for an instance whose lease the operator
    holds; the vehicle acknowledges it ``done`` after each call, untimed, as a
    vehicle carrying it out would), ``update_param`` (one sample and two
    parameters), ``get_control`` (``wait_s=0``, nothing queued). Each call is
    paired with a ``GET /healthz`` on the same connection just before it, the
    baseline: the bare round trip through the proxy plus what a trivial route
    costs. The median of ``CALLS`` pairs after ``WARMUP``; a fresh vehicle,
    instance and lease each run. Goal: each method's median within the paired
    baseline's + 3 ms ("over RTT" rows); the absolute median sits beside the
    paper's average (in the row's name).

(b) **The multilayer paper's three routes**, RTT of an echoed JSON message by
    size (64 B, 1 KiB, 8 KiB, 64 KiB of payload, a JSON string), one message in
    flight, ``ECHOES`` after ``ECHO_WARMUP``. The proxy is on the surface → cloud
    hop (the WAN); the other links are loopback.

    1. unit → surface: the underwater unit (a local unit of a real gateway agent,
       ``fleet-agent gateway`` with ``listen``, connected to its unit WebSocket as
       ``wan-uw``) publishes on ``vehicle/wan-uw/ping``; the surface unit (another
       local unit of the same gateway, ``wan-surf``, standing for a program on the
       surface computer) has subscribed and publishes the same data back on
       ``vehicle/wan-surf/pong``. The gateway delivers both ways itself: nobody
       above asked for either topic, so nothing crosses the WAN.
    2. surface → cloud: the surface's own link, without the gateway agent: the
       bench holds a socket on ``/ws/vehicle`` with a second gateway's token (the
       socket the gateway agent keeps, driven by the bench) through the proxy and
       publishes for its vehicle ``wan-link``; the cloud unit, a user's worker on
       ``/ws/client`` connected to the server directly (it runs in the cloud),
       publishes the data back on ``user/wan-cloud/pong/wan-link``.
    3. unit → cloud through the gateway: ``wan-uw`` publishes on
       ``vehicle/wan-uw/up``; the real gateway agent sends it up (its
       ``forward_up`` holds it once the worker subscribed) over its link through
       the proxy; the worker answers on ``user/wan-cloud/pong/wan-uw``, which the
       gateway brings down to the unit. A surface unit attached to the gateway
       would take this same path to the cloud.

    The gateway runs with its defaults (``batch_tick_s`` 0.1: the ops it sends up
    during a tick leave as one ``batch`` frame) and simulates one vehicle of its
    own (``wan-sim``, 1 Hz telemetry over the same link), which it must have.

Not measured: TLS (the paper's server spoke HTTP), loss or jitter on the link, a
bandwidth limit (the proxy delays every byte by the same amount whatever the
rate), several calls in flight, and the paper's media path (RTSP).
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

from bench import Metric
from bench._faults import FaultProxy
from bench._live.config import ROOT
from bench._live.server import fleet_server
from bench._proc import stop
from bench._wan_routes import ROUTE_NAMES, gateway_agent, routes, size_name, world
from bench._wan_table2 import table2

TITLE = "the paper's Table 2 and the multilayer routes through a 29 ms round trip"
ONE_WAY_S = 0.0145


# ---- the proxy, in its own process -------------------------------------------------
@contextlib.contextmanager
def wan_proxy(upstream_port: int, one_way_s: float = ONE_WAY_S) -> Iterator[int]:
    """A FaultProxy in front of ``upstream_port`` in a child process; yields its port."""
    process = subprocess.Popen(
        [sys.executable, "-m", "bench.wan", "proxy", str(upstream_port), str(one_way_s)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
    )
    try:
        assert process.stdout is not None
        line = process.stdout.readline().decode()
        if not line.strip().isdigit():
            raise RuntimeError(f"the WAN proxy did not start: {line!r}")
        yield int(line)
    finally:
        stop(process, signal.SIGTERM, 5)


def _serve_proxy(upstream_port: int, one_way_s: float) -> None:
    """The child: the proxy's port on stdout, then until SIGTERM."""
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM, signal.SIGINT})
    with FaultProxy(upstream_port, delay_s=one_way_s) as proxy:
        print(proxy.port, flush=True)
        signal.sigwait({signal.SIGTERM, signal.SIGINT})


def run(runs: int) -> list[Metric]:
    with tempfile.TemporaryDirectory(prefix="bench-wan-") as tmp:
        workdir = Path(tmp)
        with fleet_server(workdir, None) as server, wan_proxy(server.port) as wan_port:
            wan = f"http://127.0.0.1:{wan_port}"
            metrics = table2(server.base, wan, runs)
            tokens = world(server.base)
            with gateway_agent(workdir, wan_port, tokens["gateway"], None) as unit_port:
                results = asyncio.run(
                    routes(server.base, wan_port, unit_port, tokens, runs, {1, 2, 3})
                )
            # The same gateway sending each op up at once (no batch tick).
            with gateway_agent(workdir, wan_port, tokens["gateway"], 0) as unit_port:
                untick = asyncio.run(routes(server.base, wan_port, unit_port, tokens, runs, {3}))
    for (route, size), values in sorted(results.items()):
        metrics.append(Metric(f"{ROUTE_NAMES[route]}, {size_name(size)} RTT", "ms", values))
    for (_, size), values in sorted(untick.items()):
        name = f"{ROUTE_NAMES[3]}, {size_name(size)} RTT, batch_tick_s 0"
        metrics.append(Metric(name, "ms", values))
    return metrics


if __name__ == "__main__":
    if sys.argv[1:2] == ["proxy"]:
        _serve_proxy(int(sys.argv[2]), float(sys.argv[3]))
    else:
        for m in run(int(sys.argv[1]) if len(sys.argv) > 1 else 1):
            print(m.name, m.unit, [round(v, 2) for v in m.values], m.goal)
