"""The in-process bus."""

from __future__ import annotations

from server.bus import LocalBus, make_bus
from server.bus.redis_bus import RedisBus
from server.settings import Settings


def collector() -> tuple[list[tuple[str, object]], object]:
    got: list[tuple[str, object]] = []
    return got, lambda topic, message: got.append((topic, message))


async def test_publish_reaches_each_subscriber_of_the_topic_only():
    bus = LocalBus()
    a, on_a = collector()
    b, on_b = collector()
    other, on_other = collector()
    await bus.subscribe("user/a/x", on_a)
    await bus.subscribe("user/a/x", on_b)
    await bus.subscribe("user/a/y", on_other)
    await bus.publish("user/a/x", {"n": 1})
    await bus.publish("user/a/x", b"\x00\x01")
    assert a == b == [("user/a/x", {"n": 1}), ("user/a/x", b"\x00\x01")]
    assert other == []


async def test_unsubscribe_stops_delivery_and_is_idempotent():
    bus = LocalBus()
    got, handler = collector()
    subscription = await bus.subscribe("fleet", handler)
    await bus.unsubscribe(subscription)
    await bus.unsubscribe(subscription)
    await bus.publish("fleet", {"n": 1})
    assert got == []


async def test_a_failing_handler_does_not_stop_the_others():
    bus = LocalBus()
    got, handler = collector()

    def broken(topic, message):
        raise RuntimeError("boom")

    await bus.subscribe("fleet", broken)
    await bus.subscribe("fleet", handler)
    await bus.publish("fleet", {"n": 1})
    assert got == [("fleet", {"n": 1})]


async def test_local_bus_is_healthy_and_not_remote():
    async with LocalBus() as bus:
        assert bus.healthy
        assert not bus.remote


def test_make_bus_follows_the_redis_setting():
    assert isinstance(make_bus(Settings(redis_url=None)), LocalBus)
    bus = make_bus(Settings(redis_url="redis://127.0.0.1:1/0"))
    assert isinstance(bus, RedisBus)
    assert bus.remote
