"""Another replica, in its own process: ``python tests/bus/peer.py URL TOPIC...``.

Subscribes to the topics on a RedisBus, prints ``ready``, then one JSON
line per message it gets. Each line read on stdin is ``TOPIC JSON`` to
publish (``TOPIC hex:ABCD`` for bytes). Ends at end of input.
"""

from __future__ import annotations

import asyncio
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from server.bus.redis_bus import RedisBus


def show(topic: str, message: object) -> None:
    if isinstance(message, bytes):
        line = {"topic": topic, "bytes": message.hex()}
    else:
        line = {"topic": topic, "json": message}
    print(json.dumps(line), flush=True)


async def main(url: str, topics: list[str]) -> None:
    bus = RedisBus(url)
    await bus.start()
    for topic in topics:
        await bus.subscribe(topic, show)
    print("ready" if bus.healthy else "unhealthy", flush=True)
    loop = asyncio.get_running_loop()
    while line := await loop.run_in_executor(None, sys.stdin.readline):
        topic, _, payload = line.strip().partition(" ")
        if payload.startswith("hex:"):
            await bus.publish(topic, bytes.fromhex(payload[4:]))
        else:
            await bus.publish(topic, json.loads(payload))
        print(json.dumps({"published": topic}), flush=True)
    await bus.close()


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], sys.argv[2:]))
