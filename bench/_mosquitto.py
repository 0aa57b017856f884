"""Mosquitto for the benches: a broker on a free loopback port, and paho clients driven by hand.

The broker is the QoS 0 set-up both MQTT baselines use (``set_tcp_nodelay``,
no persistence, no log); :class:`MqttPump` drives paho clients from the
calling thread with ``select`` (no loop threads), so the measuring side holds
no thread switching, as the server's bench clients hold none.
"""

from __future__ import annotations

import contextlib
import select
import shutil
import socket
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import paho.mqtt.client as mqtt

from bench._proc import child_setup, free_port, stop, wait_for_port

START_WITHIN_S = 10.0


def mosquitto_binary() -> str:
    return shutil.which("mosquitto") or "/usr/sbin/mosquitto"


@contextlib.contextmanager
def mosquitto(
    workdir: Path,
    core: int | None = None,
    extra: str = "",
    name: str = "m",
    binary: str | None = None,
) -> Iterator[int]:
    """A broker on a free loopback port (config ``workdir/mosquitto-<name>.conf``); its port.

    ``core``: the core to pin it to; ``extra``: more configuration (a bridge).
    """
    binary = binary or mosquitto_binary()
    if not Path(binary).exists():
        raise RuntimeError("mosquitto is not installed (apt-get install -y mosquitto)")
    port = free_port()
    config = workdir / f"mosquitto-{name}.conf"
    config.write_text(
        f"listener {port} 127.0.0.1\n"
        "allow_anonymous true\n"
        "persistence false\n"
        "set_tcp_nodelay true\n"
        "max_packet_size 1048576\n"
        "log_dest none\n" + extra
    )
    process = subprocess.Popen(
        [binary, "-c", str(config)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        preexec_fn=child_setup(core),
    )
    try:
        wait_for_port(port, process, "mosquitto", START_WITHIN_S)
        yield port
    finally:
        stop(process)
        if process.stderr is not None:
            process.stderr.close()


def mosquitto_version() -> str:
    with contextlib.suppress(OSError, subprocess.SubprocessError):
        out = subprocess.run(
            [mosquitto_binary(), "-h"], capture_output=True, text=True, timeout=5
        ).stdout
        first = out.splitlines()[0] if out else ""
        return first.replace("mosquitto version ", "")
    return "?"


class MqttPump:
    """paho clients driven from this thread with ``select`` (no loop threads)."""

    def __init__(self) -> None:
        self.clients: list[mqtt.Client] = []

    def connect(self, port: int, name: str) -> mqtt.Client:
        """A client connected (``TCP_NODELAY``) to the broker on ``port``."""
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=name)
        done: list[bool] = []
        client.on_connect = lambda *args: done.append(True)
        client.connect("127.0.0.1", port)
        sock = client.socket()
        assert isinstance(sock, socket.socket)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.clients.append(client)
        self.until(lambda: bool(done), f"{name} could not connect to mosquitto on {port}")
        return client

    def once(self, timeout: float) -> None:
        """Write what the clients have, read what arrives within ``timeout``."""
        for client in self.clients:
            if client.want_write():
                client.loop_write()
        socks = {c.socket(): c for c in self.clients if c.socket() is not None}
        readable, _, _ = select.select(list(socks), [], [], timeout)  # type: ignore[type-var]
        for sock in readable:
            socks[sock].loop_read()
        for client in self.clients:
            client.loop_misc()

    def until(self, condition: Callable[[], bool], failure: str, within_s: float = 10) -> None:
        """Pump until ``condition()``; ``RuntimeError(failure)`` after ``within_s``."""
        deadline = time.monotonic() + within_s
        while not condition():
            if time.monotonic() > deadline:
                raise RuntimeError(failure)
            self.once(0.05)

    def subscribe(self, client: mqtt.Client, topic: str) -> None:
        """Subscribe at QoS 0 and wait for the broker's confirmation."""
        done: list[bool] = []
        client.on_subscribe = lambda *args: done.append(True)
        client.subscribe(topic, qos=0)
        self.until(lambda: bool(done), "mosquitto did not confirm the subscription")

    def close(self) -> None:
        for client in self.clients:
            with contextlib.suppress(Exception):
                client.disconnect()
                if client.want_write():
                    client.loop_write()
