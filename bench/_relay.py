"""A bare WebSocket relay on the server's stack, the floor for the pub-sub figures.

uvicorn with uvloop and the websockets-sansio protocol, permessage-deflate
off, as ``fleet-server`` runs, and a plain ASGI app: a frame that arrives on
``/pub`` is sent to every socket open on ``/sub``. No auth, no parsing, no
queue. The pub-sub section runs it beside the fleet server and Mosquitto, so
the table shows what the fleet's layer costs over the bare stack it runs on.

    python -m bench._relay PORT
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from bench._proc import child_setup, free_port, stop, wait_for_port

_subscribers: set[Any] = set()


async def app(scope: dict[str, Any], receive: Any, send: Any) -> None:
    if scope["type"] == "lifespan":
        while (await receive())["type"] != "lifespan.shutdown":
            await send({"type": "lifespan.startup.complete"})
        await send({"type": "lifespan.shutdown.complete"})
        return
    if scope["type"] != "websocket":
        return
    await receive()  # websocket.connect
    await send({"type": "websocket.accept"})
    if scope["path"] == "/sub":
        _subscribers.add(send)
        try:
            await receive()  # until the disconnect
        finally:
            _subscribers.discard(send)
        return
    while True:
        message = await receive()
        if message["type"] == "websocket.disconnect":
            return
        out = {"type": "websocket.send", "text": message.get("text"), "bytes": message.get("bytes")}
        for subscriber in list(_subscribers):
            await subscriber(out)


@contextlib.contextmanager
def bare_relay(workdir: Path, core: int | None) -> Iterator[int]:
    """The relay in its own process on a free loopback port (pinned like the server); its port."""
    port = free_port()
    log = (workdir / "relay.log").open("wb")
    process = subprocess.Popen(
        [sys.executable, "-m", "bench._relay", str(port)],
        cwd=Path(__file__).resolve().parents[1],
        stdout=log,
        stderr=subprocess.STDOUT,
        preexec_fn=child_setup(core),
    )
    try:
        wait_for_port(port, process, "bare relay", 30)
        yield port
    finally:
        stop(process)
        log.close()


def main() -> None:
    import uvicorn

    uvicorn.run(
        app,
        host="127.0.0.1",
        port=int(sys.argv[1]),
        ws="websockets-sansio",
        ws_per_message_deflate=False,
        log_level="warning",
        lifespan="on",
    )


if __name__ == "__main__":
    main()
