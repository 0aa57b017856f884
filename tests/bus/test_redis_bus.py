"""The Redis bus against a real redis-server, across two OS processes."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import sys
import time
from pathlib import Path

import pytest

from server.bus.redis_bus import RedisBus

PEER = Path(__file__).with_name("peer.py")
WAIT_S = 10.0


class Peer:
    """tests/bus/peer.py in a subprocess: another replica."""

    def __init__(self, process: asyncio.subprocess.Process) -> None:
        self.process = process

    @classmethod
    async def start(cls, url: str, *topics: str) -> Peer:
        process = await asyncio.create_subprocess_exec(
            sys.executable,
            str(PEER),
            url,
            *topics,
            stdin=asyncio.subprocess.PIPE,
            stdout=asyncio.subprocess.PIPE,
        )
        peer = cls(process)
        assert await peer.line() == "ready"
        return peer

    async def line(self) -> str:
        assert self.process.stdout is not None
        raw = await asyncio.wait_for(self.process.stdout.readline(), WAIT_S)
        assert raw, "the peer process ended"
        return raw.decode().strip()

    async def message(self) -> dict:
        return json.loads(await self.line())

    async def publish(self, topic: str, payload: str) -> None:
        assert self.process.stdin is not None
        self.process.stdin.write(f"{topic} {payload}\n".encode())
        await self.process.stdin.drain()
        assert await self.message() == {"published": topic}

    async def close(self) -> None:
        if self.process.stdin is not None:
            self.process.stdin.close()
        try:
            await asyncio.wait_for(self.process.wait(), WAIT_S)
        except TimeoutError:
            self.process.kill()
            await self.process.wait()


async def until(predicate, what: str, timeout_s: float = WAIT_S) -> None:
    """Wait for ``predicate()`` to hold, polling, at most ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out waiting for {what}")
        await asyncio.sleep(0.01)


def inbox() -> tuple[asyncio.Queue, object]:
    queue: asyncio.Queue = asyncio.Queue()
    return queue, lambda topic, message: queue.put_nowait((topic, message))


async def next_of(queue: asyncio.Queue):
    return await asyncio.wait_for(queue.get(), WAIT_S)


async def test_messages_cross_processes_both_ways(redis_server):
    peer = await Peer.start(redis_server.url, "user/a/down")
    try:
        async with RedisBus(redis_server.url) as bus:
            assert bus.healthy
            await bus.publish("user/a/down", {"n": 1, "text": "héllo"})
            await bus.publish("user/a/down", b"\x00\xffframe")
            await bus.publish("user/a/elsewhere", {"n": 2})  # nobody subscribed there
            assert await peer.message() == {
                "topic": "user/a/down",
                "json": {"n": 1, "text": "héllo"},
            }
            assert await peer.message() == {"topic": "user/a/down", "bytes": "00ff6672616d65"}

            queue, handler = inbox()
            await bus.subscribe("user/a/up", handler)
            await peer.publish("user/a/up", '{"result": [1, 2]}')
            await peer.publish("user/a/up", "hex:0102")
            assert await next_of(queue) == ("user/a/up", {"result": [1, 2]})
            assert await next_of(queue) == ("user/a/up", b"\x01\x02")
    finally:
        await peer.close()


async def test_own_publish_is_delivered_once_locally(redis_server):
    async with RedisBus(redis_server.url) as bus, RedisBus(redis_server.url) as other:
        queue, handler = inbox()
        await bus.subscribe("user/a/x", handler)
        await bus.publish("user/a/x", {"n": 1})
        # Redis sends our echo before the other replica's marker: once the
        # marker is here, a duplicate would have been too.
        await other.publish("user/a/x", {"marker": True})
        assert await next_of(queue) == ("user/a/x", {"n": 1})
        assert await next_of(queue) == ("user/a/x", {"marker": True})
        assert queue.empty()


async def test_unsubscribe_stops_remote_delivery(redis_server):
    async with RedisBus(redis_server.url) as bus, RedisBus(redis_server.url) as other:
        queue, handler = inbox()
        marker_queue, marker_handler = inbox()
        subscription = await bus.subscribe("user/a/x", handler)
        await bus.subscribe("user/a/marker", marker_handler)
        await bus.unsubscribe(subscription)
        await other.publish("user/a/x", {"n": 1})
        await other.publish("user/a/marker", {"n": 2})
        assert await next_of(marker_queue) == ("user/a/marker", {"n": 2})
        assert queue.empty()


async def test_degrades_to_local_delivery_and_recovers(redis_server):
    async with RedisBus(redis_server.url) as bus, RedisBus(redis_server.url) as other:
        queue, handler = inbox()
        await bus.subscribe("user/a/x", handler)
        assert bus.healthy

        redis_server.stop()
        await until(lambda: not bus.healthy, "the bus to notice Redis is gone")
        await bus.publish("user/a/x", {"while": "down"})
        assert await next_of(queue) == ("user/a/x", {"while": "down"})
        assert bus.local_only_publishes == 1

        redis_server.start()
        assert await bus.wait_healthy(WAIT_S)
        assert await other.wait_healthy(WAIT_S)
        await other.publish("user/a/x", {"after": "restart"})
        assert await next_of(queue) == ("user/a/x", {"after": "restart"})


async def test_starts_unhealthy_without_redis_and_serves_locally(redis_server):
    url = redis_server.url
    redis_server.stop()
    bus = RedisBus(url, timeout_s=0.2)
    async with bus:
        assert not bus.healthy
        queue, handler = inbox()
        await bus.subscribe("user/a/x", handler)
        await bus.publish("user/a/x", {"n": 1})
        assert await next_of(queue) == ("user/a/x", {"n": 1})
        redis_server.start()
        assert await bus.wait_healthy(WAIT_S)
        peer = await Peer.start(url, "user/a/none")
        try:
            await peer.publish("user/a/x", '{"n": 2}')
            assert await next_of(queue) == ("user/a/x", {"n": 2})
        finally:
            await peer.close()


async def test_a_redis_that_hangs_is_noticed_and_the_bus_serves_locally(redis_server):
    """Redis stopped (SIGSTOP: its connections open, nothing answered), as a network that
    drops packets without a reset: the bus said it was healthy, /readyz ok, while every
    publish to the other replicas timed out."""
    async with RedisBus(redis_server.url) as bus:
        assert bus.healthy
        queue, handler = inbox()
        await bus.subscribe("user/a/x", handler)
        assert redis_server.process is not None
        os.kill(redis_server.process.pid, signal.SIGSTOP)
        try:
            await until(lambda: not bus.healthy, "the bus to notice Redis hangs")
            await bus.publish("user/a/x", {"while": "hung"})
            assert await next_of(queue) == ("user/a/x", {"while": "hung"})
        finally:
            os.kill(redis_server.process.pid, signal.SIGCONT)
        assert await bus.wait_healthy(WAIT_S)
