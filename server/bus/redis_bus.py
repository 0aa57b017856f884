"""The bus across replicas: Redis pub/sub through redis-py's asyncio client.

Each topic is a Redis channel ``<prefix>t:<topic>``; the channel is
subscribed while this replica has at least one local handler for it. A
message travels as one byte of kind (``j`` JSON, ``b`` bytes), the 8-byte id
of the publishing replica, then the body. A publish is delivered to this
replica's handlers at once; its echo from Redis is recognised by the replica
id and skipped, so nothing is delivered twice here.

When Redis goes away (or hangs: a connection quiet for a while is pinged, and no
answer in the timeout counts as gone) the bus keeps serving this replica's own subscribers
(local delivery), reports ``healthy = False`` (``/readyz``), and reconnects
with backoff, subscribing again to every topic that has a local handler.
Messages published anywhere while a replica is cut off do not reach it (Redis
pub/sub keeps nothing): commands are redelivered by their own life cycle, and
the HTTP endpoints remain the fallback.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import secrets
from collections.abc import Awaitable
from typing import Any

from redis.asyncio import Redis
from redis.asyncio.client import PubSub
from redis.asyncio.retry import Retry
from redis.backoff import NoBackoff
from redis.exceptions import RedisError

from server.bus.base import (
    KEEP_BUDGET_BYTES,
    KEEP_MAX_BYTES,
    KEEP_TTL_S,
    Bus,
    Handler,
    Kept,
    LocalRouter,
    Message,
    Subscription,
)

__all__ = ["RedisBus"]

log = logging.getLogger(__name__)

_JSON = b"j"
_BYTES = b"b"
_ORIGIN_BYTES = 8
_READ_TIMEOUT_S = 1.0
#: A connection quiet this long is asked for a PONG: a Redis that hangs (stopped, or a
#: network that drops packets without a reset) answers nothing and raises no error.
_PING_AFTER_S = 2.0
#: How long :meth:`RedisBus.close` waits for the connection loop to end.
_STOP_WAIT_S = 5.0


class RedisBus(Bus):
    remote = True

    def __init__(
        self,
        url: str,
        *,
        prefix: str = "fleet:",
        timeout_s: float = 2.0,
        reconnect_min_s: float = 0.05,
        reconnect_max_s: float = 2.0,
    ) -> None:
        self._url = url
        self._topic_prefix = f"{prefix}t:".encode()
        self._kept_prefix = f"{prefix}k:"
        #: Always subscribed, so the connection lives (and fails) even with no topic.
        self._control_channel = f"{prefix}replicas".encode()
        self._timeout_s = timeout_s
        self._reconnect_min_s = reconnect_min_s
        self._reconnect_max_s = reconnect_max_s
        self.replica_id = secrets.token_bytes(_ORIGIN_BYTES)
        self._router = LocalRouter()
        self._kept: Kept[dict[str, Any]] = Kept(KEEP_BUDGET_BYTES)
        self._redis: Redis | None = None
        self._pubsub: PubSub | None = None
        self._lock = asyncio.Lock()
        self._confirmations: dict[bytes, list[asyncio.Future[None]]] = {}
        self._healthy = asyncio.Event()
        self._closing = asyncio.Event()
        self._task: asyncio.Task[None] | None = None
        #: Publishes that reached this replica only (Redis down or failing).
        self.local_only_publishes = 0

    @property
    def healthy(self) -> bool:
        return self._healthy.is_set()

    async def wait_healthy(self, timeout_s: float) -> bool:
        """Wait until connected to Redis, at most ``timeout_s``; whether it is."""
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._healthy.wait(), timeout_s)
        return self.healthy

    async def start(self) -> None:
        """Start the connection loop; wait a moment for Redis, but never fail for it."""
        if self._task is not None:
            return
        self._redis = Redis.from_url(
            self._url,
            socket_timeout=self._timeout_s,
            socket_connect_timeout=self._timeout_s,
            retry=Retry(NoBackoff(), 0),
        )
        self._task = asyncio.create_task(self._run(), name="redis-bus")
        if not await self.wait_healthy(self._timeout_s):
            log.warning("redis bus: Redis unreachable at start; serving this replica only")

    async def close(self) -> None:
        """End the connection loop and the connection. The loop is told by ``_closing``
        as well as cancelled (a cancellation can be lost inside a read with a timeout), and
        is waited for :data:`_STOP_WAIT_S` at most."""
        self._closing.set()
        if self._task is not None:
            self._task.cancel()
            _, late = await asyncio.wait([self._task], timeout=_STOP_WAIT_S)
            if late:
                log.error("redis bus: the connection loop did not stop in time")
            self._task = None
        if self._redis is not None:
            with contextlib.suppress(RedisError, OSError):
                await self._redis.aclose()
            self._redis = None

    # -- publish / subscribe ----------------------------------------------------

    async def publish(self, topic: str, message: Message) -> None:
        self._router.deliver(topic, message)
        if not self.healthy or self._redis is None:
            self.local_only_publishes += 1
            return
        if isinstance(message, bytes | bytearray | memoryview):
            body = _BYTES + self.replica_id + bytes(message)
        else:
            body = _JSON + self.replica_id + json.dumps(message, separators=(",", ":")).encode()
        try:
            await self._redis.publish(self._channel(topic), body)
        except (RedisError, OSError) as exc:
            self.local_only_publishes += 1
            log.warning("redis bus: publish on %s reached this replica only: %s", topic, exc)

    def keep(self, topic: str, message: dict[str, Any], text: str) -> Awaitable[None] | None:
        """Here, and in Redis for the other replicas (for ``KEEP_TTL_S``; one too large is
        deleted there: it is no longer the latest). Awaited before the publish is sent, so
        a replica that subscribes and then reads the kept message misses nothing."""
        super().keep(topic, message, text)
        if not self.healthy or self._redis is None:
            return None
        return self._keep_remote(topic, message, len(text))

    async def _keep_remote(self, topic: str, message: dict[str, Any], size: int) -> None:
        assert self._redis is not None
        key = self._kept_prefix + topic
        try:
            if size > KEEP_MAX_BYTES:
                await self._redis.delete(key)
            else:
                body = json.dumps(message, separators=(",", ":"))
                await self._redis.set(key, body, ex=KEEP_TTL_S)
        except (RedisError, OSError) as exc:
            log.warning("redis bus: the latest of %s kept on this replica only: %s", topic, exc)

    async def kept(self, topic: str) -> dict[str, Any] | None:
        """From Redis (another replica may have published it); this replica's while Redis
        is down."""
        if not self.healthy or self._redis is None:
            return self._kept.get(topic)
        try:
            raw = await self._redis.get(self._kept_prefix + topic)
        except (RedisError, OSError):
            return self._kept.get(topic)
        if raw is None:
            return None
        try:
            found = json.loads(raw)
        except ValueError:
            return None
        return found if isinstance(found, dict) else None

    async def subscribe(self, topic: str, handler: Handler) -> Subscription:
        subscription, first = self._router.add(topic, handler)
        if first:
            await self._subscribe_remote(self._channel(topic))
        return subscription

    async def unsubscribe(self, subscription: Subscription) -> None:
        if not self._router.remove(subscription):
            return
        async with self._lock:
            pubsub = self._pubsub
            if pubsub is None or self._router.has(subscription.topic):
                return
            with contextlib.suppress(RedisError, OSError):
                await pubsub.unsubscribe(self._channel(subscription.topic))

    async def _subscribe_remote(self, channel: bytes) -> None:
        """Subscribe ``channel`` and wait for Redis to confirm (a reconnect does it if down)."""
        confirmed: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        async with self._lock:
            pubsub = self._pubsub
            if pubsub is None:
                return
            self._confirmations.setdefault(channel, []).append(confirmed)
            try:
                await pubsub.subscribe(channel)
            except (RedisError, OSError) as exc:
                log.warning("redis bus: subscribe failed, will retry on reconnect: %s", exc)
                self._drop_confirmation(channel, confirmed)
                return
        try:
            await asyncio.wait_for(confirmed, self._timeout_s)
        except TimeoutError:
            log.warning("redis bus: no confirmation of %r in %ss", channel, self._timeout_s)
            self._drop_confirmation(channel, confirmed)

    def _drop_confirmation(self, channel: bytes, future: asyncio.Future[None]) -> None:
        waiting = self._confirmations.get(channel, [])
        if future in waiting:
            waiting.remove(future)
        if not waiting:
            self._confirmations.pop(channel, None)

    def _channel(self, topic: str) -> bytes:
        return self._topic_prefix + topic.encode()

    # -- the connection loop ----------------------------------------------------

    async def _run(self) -> None:
        delay = self._reconnect_min_s
        while not self._closing.is_set():
            assert self._redis is not None
            pubsub = self._redis.pubsub()
            try:
                async with self._lock:
                    channels = [self._channel(t) for t in self._router.topics()]
                    await pubsub.subscribe(self._control_channel, *channels)
                    self._pubsub = pubsub
                self._healthy.set()
                log.info("redis bus: connected, %d topics subscribed", len(channels))
                delay = self._reconnect_min_s
                await self._listen(pubsub)
            except (RedisError, OSError) as exc:
                if self.healthy:
                    log.warning("redis bus: lost Redis (%s); serving this replica only", exc)
            except Exception:
                # Whatever it was, the loop lives on: reconnect rather than stay down.
                log.exception("redis bus: unexpected failure; reconnecting")
            finally:
                self._pubsub = None
                self._healthy.clear()
                self._release_confirmations()
                with contextlib.suppress(Exception):
                    await pubsub.aclose()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._closing.wait(), delay)
            delay = min(delay * 2, self._reconnect_max_s)

    async def _listen(self, pubsub: PubSub) -> None:
        """Hand each message on, until the connection fails; one that stays quiet is
        pinged, and no PONG within the timeout is a failure too (``healthy`` false,
        ``/readyz`` degraded, publishes to this replica only until Redis answers again)."""
        loop = asyncio.get_running_loop()
        heard = loop.time()
        pinged: float | None = None
        while not self._closing.is_set():
            message = await pubsub.get_message(timeout=_READ_TIMEOUT_S)
            now = loop.time()
            if message is not None:
                heard, pinged = now, None
                if message.get("type") != "pong":
                    self._on_message(message)
                continue
            if pinged is not None and now - pinged > self._timeout_s:
                raise ConnectionError(f"no answer from Redis to a ping in {self._timeout_s} s")
            if pinged is None and now - heard >= _PING_AFTER_S:
                await pubsub.ping()
                pinged = now

    def _release_confirmations(self) -> None:
        """Subscribers waiting on a lost connection go on (the reconnect subscribes)."""
        for waiting in self._confirmations.values():
            for future in waiting:
                if not future.done():
                    future.set_result(None)
        self._confirmations.clear()

    def _on_message(self, message: dict[str, object]) -> None:
        kind = message.get("type")
        channel = message.get("channel")
        if not isinstance(channel, bytes):
            return
        if kind == "subscribe":
            for future in self._confirmations.pop(channel, []):
                if not future.done():
                    future.set_result(None)
            return
        data = message.get("data")
        if kind != "message" or not isinstance(data, bytes) or channel == self._control_channel:
            return
        head = 1 + _ORIGIN_BYTES
        if len(data) < head or data[1:head] == self.replica_id:
            return
        topic = channel[len(self._topic_prefix) :].decode()
        body = data[head:]
        if data[:1] == _JSON:
            try:
                decoded: Message = json.loads(body)
            except ValueError:
                log.warning("redis bus: undecodable message on %s dropped", topic)
                return
        else:
            decoded = body
        self._router.deliver(topic, decoded)
