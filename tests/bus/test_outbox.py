"""The per-connection outbox: bound, lagging, critical frames, latest-wins, throttle."""

from __future__ import annotations

import asyncio
import json

import pytest

from server.api.outbox import Outbox

WAIT_S = 5.0


class Socket:
    """A fake socket whose sends block while ``gate`` is closed."""

    def __init__(self, *, open_gate: bool = True, fail_on: int | None = None) -> None:
        self.frames: list[str | bytes] = []
        self.gate = asyncio.Event()
        if open_gate:
            self.gate.set()
        self.entered = asyncio.Event()
        self.fail_on = fail_on

    async def send(self, frame: str | bytes) -> None:
        self.entered.set()
        await self.gate.wait()
        if self.fail_on is not None and len(self.frames) == self.fail_on:
            raise ConnectionError("socket closed")
        self.frames.append(frame)

    def send_nowait(self, frame: str | bytes) -> bool:
        """What the server's protocol offers: a send at once when nothing holds it up."""
        if not self.gate.is_set():
            self.entered.set()
            return False
        if self.fail_on is not None and len(self.frames) == self.fail_on:
            raise ConnectionError("socket closed")
        self.frames.append(frame)
        return True


async def wait_idle(outbox: Outbox) -> None:
    await asyncio.wait_for(outbox.wait_idle(), WAIT_S)


async def stalled(max_size: int) -> tuple[Socket, Outbox]:
    """An outbox whose writer is stuck sending its first frame, "first"."""
    socket = Socket(open_gate=False)
    outbox = Outbox(socket.send, max_size=max_size)
    outbox.start()
    outbox.put("first")
    await asyncio.wait_for(socket.entered.wait(), WAIT_S)
    return socket, outbox


def lagging(frame: str | bytes) -> dict:
    body = json.loads(frame)
    assert body["op"] == "lagging"
    return body


async def test_frames_go_in_order():
    socket = Socket()
    async with Outbox(socket.send) as outbox:
        for i in range(5):
            outbox.put(f"m{i}")
        outbox.put(b"\x00binary")
        await wait_idle(outbox)
    assert socket.frames == ["m0", "m1", "m2", "m3", "m4", b"\x00binary"]
    assert outbox.sent == 6
    assert outbox.dropped == 0


async def test_when_full_the_oldest_is_dropped_counted_and_told():
    socket, outbox = await stalled(max_size=3)
    for name in ("b", "c", "d", "e", "f"):
        outbox.put(name)
    assert len(outbox) == 3
    assert outbox.dropped == 2
    socket.gate.set()
    await wait_idle(outbox)
    await outbox.close()
    assert socket.frames[0] == "first"
    assert lagging(socket.frames[1]) == {"op": "lagging", "dropped": 2, "total": 2}
    assert socket.frames[2:] == ["d", "e", "f"]


async def test_lagging_counts_only_the_drops_since_the_last_notice():
    socket, outbox = await stalled(max_size=1)
    outbox.put("a")
    outbox.put("b")  # drops a
    socket.gate.set()
    await wait_idle(outbox)
    socket.gate.clear()
    socket.entered.clear()
    outbox.put("c")  # the writer blocks sending c
    await asyncio.wait_for(socket.entered.wait(), WAIT_S)
    outbox.put("d")
    outbox.put("e")  # drops d
    outbox.put("f")  # drops e
    socket.gate.set()
    await wait_idle(outbox)
    await outbox.close()
    assert socket.frames[:3] == ["first", socket.frames[1], "b"]
    assert socket.frames[3] == "c"
    assert socket.frames[5] == "f"
    notices = [lagging(socket.frames[1]), lagging(socket.frames[4])]
    assert [(n["dropped"], n["total"]) for n in notices] == [(1, 1), (2, 3)]


async def test_critical_frames_are_never_dropped_and_go_first():
    socket, outbox = await stalled(max_size=2)
    outbox.put("old-1")
    outbox.put("old-2")
    for i in range(5):
        outbox.put(f"stop-{i}", critical=True)
    outbox.put("late")  # the queue holds only critical frames beside the two olds
    assert outbox.dropped == 1
    socket.gate.set()
    await wait_idle(outbox)
    await outbox.close()
    assert socket.frames[:6] == ["first", "stop-0", "stop-1", "stop-2", "stop-3", "stop-4"]
    assert lagging(socket.frames[6])["dropped"] == 1
    assert socket.frames[7:] == ["old-2", "late"]


async def test_a_full_queue_of_critical_frames_drops_the_new_ordinary_one():
    socket, outbox = await stalled(max_size=2)
    outbox.put("stop-0", critical=True)
    outbox.put("stop-1", critical=True)
    outbox.put("stop-2", critical=True)
    outbox.put("event")
    assert outbox.dropped == 1
    socket.gate.set()
    await wait_idle(outbox)
    await outbox.close()
    assert socket.frames[:4] == ["first", "stop-0", "stop-1", "stop-2"]
    assert lagging(socket.frames[4])["dropped"] == 1
    assert len(socket.frames) == 5


async def test_latest_wins_replaces_the_waiting_frame_of_its_topic():
    socket, outbox = await stalled(max_size=10)
    outbox.put(b"cam-1", topic="vehicle/v/camera", latest_wins=True)
    outbox.put("telemetry", topic="vehicle/v/telemetry")
    outbox.put(b"cam-2", topic="vehicle/v/camera", latest_wins=True)
    outbox.put(b"cam-3", topic="vehicle/v/camera", latest_wins=True)
    outbox.put(b"sonar-1", topic="vehicle/v/sonar", latest_wins=True)
    socket.gate.set()
    await wait_idle(outbox)
    outbox.put(b"cam-4", topic="vehicle/v/camera", latest_wins=True)  # none waiting now
    await wait_idle(outbox)
    await outbox.close()
    assert socket.frames == ["first", b"cam-3", "telemetry", b"sonar-1", b"cam-4"]
    assert outbox.superseded == 2
    assert outbox.dropped == 0


async def test_a_dropped_latest_wins_frame_is_not_replaced_later():
    socket, outbox = await stalled(max_size=1)
    outbox.put(b"cam-1", topic="cam", latest_wins=True)
    outbox.put("event")  # drops cam-1
    outbox.put(b"cam-2", topic="cam", latest_wins=True)  # drops event, waits on its own
    socket.gate.set()
    await wait_idle(outbox)
    await outbox.close()
    assert socket.frames[-1] == b"cam-2"
    assert outbox.dropped == 2


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


async def test_throttle_sends_the_first_then_the_latest_after_the_interval():
    socket = Socket()
    clock = Clock()
    async with Outbox(socket.send, clock=clock) as outbox:
        outbox.put("v1", topic="t", throttle_ms=50)
        clock.now += 0.01
        for value in ("v2", "v3", "v4"):
            outbox.put(value, topic="t", throttle_ms=50)
        outbox.put("other", topic="u")  # another topic, not throttled
        outbox.put("stop", critical=True, topic="t", throttle_ms=50)  # critical: no throttle
        clock.now += 0.05
        await wait_idle(outbox)
    # The writer first runs after every put: the critical frame leads.
    assert socket.frames == ["stop", "v1", "other", "v4"]


async def test_forget_drops_a_held_throttled_frame():
    socket = Socket()
    clock = Clock()
    async with Outbox(socket.send, clock=clock) as outbox:
        outbox.put("v1", topic="t", throttle_ms=1000)
        outbox.put("v2", topic="t", throttle_ms=1000)
        outbox.forget("t")
        outbox.put("done")
        await wait_idle(outbox)
    assert socket.frames == ["v1", "done"]


async def test_a_failing_send_stops_the_writer_and_later_puts_are_ignored():
    socket = Socket(fail_on=1)
    outbox = Outbox(socket.send)
    outbox.start()
    outbox.put("a")
    outbox.put("b")
    await asyncio.wait_for(outbox.closed.wait(), WAIT_S)
    assert isinstance(outbox.error, ConnectionError)
    outbox.put("c")
    assert len(outbox) == 0
    assert socket.frames == ["a"]
    await outbox.close()


async def test_close_stops_a_blocked_writer():
    socket, outbox = await stalled(max_size=5)
    outbox.put("never")
    await asyncio.wait_for(outbox.close(), WAIT_S)
    assert outbox.closed.is_set()
    assert socket.frames == []


def test_max_size_must_be_positive():
    async def send(frame):  # pragma: no cover - never called
        pass

    with pytest.raises(ValueError):
        Outbox(send, max_size=0)


async def test_a_send_that_must_wait_is_finished_by_the_writer_in_order():
    socket = Socket()
    async with Outbox(socket.send, send_nowait=socket.send_nowait) as outbox:
        outbox.put("a")  # the writer is idle: sent from put itself
        await wait_idle(outbox)
        socket.gate.clear()
        socket.entered.clear()
        outbox.put("b")  # begins, then waits on the closed gate
        outbox.put("c")
        await asyncio.wait_for(socket.entered.wait(), WAIT_S)
        assert socket.frames == ["a"]
        socket.gate.set()
        await wait_idle(outbox)
    assert socket.frames == ["a", "b", "c"]
    assert outbox.sent == 3


async def test_a_send_failing_while_the_writer_is_idle_stops_the_outbox():
    socket = Socket(fail_on=1)
    async with Outbox(socket.send, send_nowait=socket.send_nowait) as outbox:
        outbox.put("a")
        await wait_idle(outbox)
        outbox.put("b")
        await asyncio.wait_for(outbox.closed.wait(), WAIT_S)
        assert isinstance(outbox.error, ConnectionError)
        outbox.put("c")
    assert socket.frames == ["a"]


async def test_a_frame_held_by_the_throttle_goes_when_due_without_another_put():
    socket = Socket()
    async with Outbox(socket.send, send_nowait=socket.send_nowait) as outbox:  # real clock
        await wait_idle(outbox)  # the writer is idle: puts send from put itself
        outbox.put("v1", topic="t", throttle_ms=50)
        outbox.put("v2", topic="t", throttle_ms=50)  # held back for the interval
        assert socket.frames == ["v1"]
        await wait_idle(outbox)  # idle only once the held frame went
        assert socket.frames == ["v1", "v2"]


def _writers() -> int:
    return sum(1 for t in asyncio.all_tasks() if t.get_name() == "outbox-writer")


async def test_no_writer_task_until_a_frame_has_to_wait():
    socket = Socket()
    async with Outbox(socket.send, send_nowait=socket.send_nowait) as outbox:
        for n in range(100):
            outbox.put(f"f{n}")
        assert _writers() == 0  # every frame went out from put
        socket.gate.clear()
        outbox.put("waits")
        outbox.put("after")
        assert _writers() == 1
        socket.gate.set()
        await wait_idle(outbox)
        outbox.put("again")  # the writer is parked again: sent from put
    assert socket.frames == [*(f"f{n}" for n in range(100)), "waits", "after", "again"]
    assert _writers() == 0
