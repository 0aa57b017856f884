"""A connection's outgoing queue and its one writer task.

Everything a WebSocket sends goes through its :class:`Outbox`: the bus
handler and the op loop only ``put`` frames (never block), and one writer
task ``await``\\ s ``send`` for each in turn, so a slow socket never stalls the
fan-out to the others. When the writer is idle and the socket can take a
frame at once (``send_nowait``, offered by the server's WebSocket protocol),
``put`` sends it itself (see :meth:`Outbox._send_eagerly`); anything that
must wait is sent by the writer.

- **Bounded.** With ``max_size`` frames waiting, a new frame drops the
  oldest waiting frame that is not critical; the drops are counted and the
  client is told before the next frame with ``{"op": "lagging",
  "dropped": n}``. With more than ``max_bytes`` waiting (a reader too slow for
  what it subscribed to), the outbox gives up: everything waiting is let go at
  once, nothing more is taken, and ``on_overflow`` is called (the socket is
  closed with a code that says so).
- **Critical frames** (a ``stop`` command push) are never dropped, and go
  before every other waiting frame.
- **Latest wins** (binary media topics): a new frame on a topic replaces the
  one of that topic still waiting.
- **Throttle** (a subscription's ``throttle_ms``): at most one frame per
  topic every N ms, the latest value held back and sent when the interval
  is over.
- **Timing.** A frame may carry a ``stamp`` (the wall-clock time its message
  was published, seconds since the epoch); once the frame is written,
  ``on_written(stamp)`` is called (the server → operator hop in
  ``/metrics``). A frame a throttle held back loses its stamp: its wait was
  asked for.

``send`` is any coroutine taking a text or binary frame
(``websocket.send_text`` / ``send_bytes`` behind one function), so the
outbox is tested without a socket; ``send_nowait``, when given, writes a
frame at once if the socket can take it without waiting and says whether it
did.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections import deque
from collections.abc import Callable, Coroutine
from types import TracebackType
from typing import Any, Self

from fleet_protocol.throttle import Throttle
from fleet_protocol.ws import LaggingPush

__all__ = ["DEFAULT_MAX_QUEUE", "Frame", "LazyEvent", "Outbox"]

log = logging.getLogger(__name__)

Frame = str | bytes
DEFAULT_MAX_QUEUE = 1000


class LazyEvent(asyncio.Event):
    """An :class:`asyncio.Event` that makes its queue of waiters at its first wait.

    A socket holds several events (its outbox's, its inbox's) that are mostly
    set and cleared, seldom waited on; ``asyncio.Event`` makes a ``deque`` for
    every one at once, 624 bytes each, which at 10,000 sockets came to over
    40 MB of empty queues. Setting an event nobody waited on walks the shared
    empty tuple.
    """

    _NONE_WAITING: Any = ()

    def __init__(self) -> None:
        self._waiters = self._NONE_WAITING
        self._value = False

    async def wait(self) -> Any:
        if self._waiters is self._NONE_WAITING:
            self._waiters = deque()
        return await super().wait()


class _Entry:
    __slots__ = ("frame", "stamp", "topic")

    def __init__(self, frame: Frame, topic: str | None, stamp: float | None = None) -> None:
        self.frame = frame
        self.topic = topic
        self.stamp = stamp


#: An outbox's queue before its first frame (read as empty; written, it becomes a deque).
_NO_ENTRIES: Any = ()


class Outbox:
    def __init__(
        self,
        send: Callable[[Frame], Coroutine[Any, Any, None]],
        *,
        send_nowait: Callable[[Frame], bool] | None = None,
        max_size: int = DEFAULT_MAX_QUEUE,
        max_bytes: int | None = None,
        on_overflow: Callable[[], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
        on_written: Callable[[float], None] | None = None,
    ) -> None:
        if max_size < 1:
            raise ValueError("max_size is at least 1")
        self._send = send
        self._send_nowait = send_nowait
        self.max_size = max_size
        self.max_bytes = max_bytes
        self._on_overflow = on_overflow
        self._on_written = on_written
        #: Size of the frames waiting (characters of a text frame, bytes of a binary one).
        self.queued_bytes = 0
        #: The reader fell ``max_bytes`` behind: the outbox let everything go.
        self.overflowed = False
        self._clock = clock
        # The two queues are made at their first frame (most sockets never queue one: a
        # deque is 624 bytes); until then each is the shared empty tuple.
        self._critical: deque[_Entry] = _NO_ENTRIES
        self._normal: deque[_Entry] = _NO_ENTRIES
        #: topic -> its waiting entry, for latest-wins topics.
        self._latest: dict[str, _Entry] = {}
        #: (frame, latest_wins) held back per topic by a throttle.
        self._throttle: Throttle[tuple[Frame, bool]] = Throttle()
        self._wakeup = LazyEvent()
        self._idle = LazyEvent()
        self._idle.set()
        self._task: asyncio.Task[None] | None = None
        #: ``start`` was called: the writer runs, or is made at the first frame that waits.
        self._started = False
        #: The writer waits for work (nothing queued, nothing being sent).
        self._parked = False
        self._unreported_drops = 0
        self.closed = LazyEvent()
        #: Why the writer stopped, when ``send`` failed.
        self.error: BaseException | None = None
        self.sent = 0
        self.dropped = 0
        self.superseded = 0

    # -- the producers' side ----------------------------------------------------

    def put(
        self,
        frame: Frame,
        *,
        critical: bool = False,
        topic: str | None = None,
        latest_wins: bool = False,
        throttle_ms: int = 0,
        stamp: float | None = None,
    ) -> None:
        """Queue ``frame``; never blocks, never raises for a full queue.

        ``topic`` names the frame's topic for ``latest_wins`` and
        ``throttle_ms``. A critical frame ignores both and is never dropped.
        ``stamp``: handed to ``on_written`` once the frame is written.
        """
        if self.closed.is_set():
            return
        if (
            self._parked
            and self._send_nowait is not None
            and not self._normal
            and not self._critical
            and not self._throttle
            and not self._unreported_drops
            and (topic is None or throttle_ms <= 0)
            and self._try_send(frame, stamp)
        ):
            return  # nothing waited or was held back: the frame went out at once, unqueued
        if critical:
            self._critical_queue().append(_Entry(frame, None, stamp))
            self.queued_bytes += len(frame)
        elif topic is not None and throttle_ms > 0:
            if self._throttle.offer(topic, (frame, latest_wins), throttle_ms / 1000, self._clock()):
                self._enqueue(frame, topic, latest_wins, stamp)
        else:
            self._enqueue(frame, topic, latest_wins, stamp)
        if self.max_bytes is not None and self.queued_bytes > self.max_bytes:
            self._overflow()
            return
        if self._parked and self._send_nowait is not None and self._send_eagerly():
            return
        self._idle.clear()
        self._wakeup.set()
        if self._task is None and self._started:
            self._task = asyncio.create_task(self._write(), name="outbox-writer")

    def _critical_queue(self) -> deque[_Entry]:
        if self._critical is _NO_ENTRIES:
            self._critical = deque()
        return self._critical

    def _normal_queue(self) -> deque[_Entry]:
        if self._normal is _NO_ENTRIES:
            self._normal = deque()
        return self._normal

    def forget(self, topic: str) -> None:
        """Drop a topic's throttle state and held frame (on unsubscribe)."""
        self._throttle.forget(topic)

    def __len__(self) -> int:
        """Frames waiting (throttled ones held back not included)."""
        return len(self._critical) + len(self._normal)

    def _enqueue(
        self, frame: Frame, topic: str | None, latest_wins: bool, stamp: float | None = None
    ) -> None:
        if latest_wins and topic is not None:
            waiting = self._latest.get(topic)
            if waiting is not None:
                self.queued_bytes += len(frame) - len(waiting.frame)
                waiting.frame = frame
                waiting.stamp = stamp
                self.superseded += 1
                return
        if len(self) >= self.max_size:
            if not self._normal:
                self._count_drop()  # only critical frames wait: the new one goes
                return
            oldest = self._normal.popleft()
            self.queued_bytes -= len(oldest.frame)
            if oldest.topic is not None and self._latest.get(oldest.topic) is oldest:
                del self._latest[oldest.topic]
            self._count_drop()
        entry = _Entry(frame, topic, stamp)
        self._normal_queue().append(entry)
        self.queued_bytes += len(frame)
        if latest_wins and topic is not None:
            self._latest[topic] = entry

    def _overflow(self) -> None:
        """The reader is ``max_bytes`` behind: let everything go, take nothing more."""
        self.overflowed = True
        self._release()
        self.closed.set()
        self._idle.set()
        self._wakeup.set()
        log.info("outbox: over %s bytes waiting; the reader is too slow", self.max_bytes)
        if self._on_overflow is not None:
            self._on_overflow()

    def _release(self) -> None:
        self._critical = self._normal = _NO_ENTRIES
        self._latest.clear()
        self._throttle = Throttle()
        self.queued_bytes = 0

    def _count_drop(self) -> None:
        self.dropped += 1
        self._unreported_drops += 1

    # -- the writer ---------------------------------------------------------------

    def start(self) -> None:
        """Start writing. With ``send_nowait`` the writer task is made only when a frame
        has to wait for the socket (most sockets never need one: each frame goes out from
        ``put``); until then the outbox is as a parked writer leaves it."""
        if self._started:
            return
        self._started = True
        if self._send_nowait is not None:
            self._parked = True
        else:
            self._task = asyncio.create_task(self._write(), name="outbox-writer")

    async def close(self) -> None:
        """Stop the writer; frames still waiting are not sent, and let go."""
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None
        self.closed.set()
        self._idle.set()
        self._release()

    async def wait_idle(self) -> None:
        """Until nothing waits or is held back (or the writer stopped)."""
        await self._idle.wait()

    async def __aenter__(self) -> Self:
        self.start()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()

    def _next(self) -> _Entry | None:
        if self._throttle:
            for topic, (frame, latest_wins) in self._throttle.due(self._clock()):
                self._enqueue(frame, topic, latest_wins)
        if self._critical:
            entry = self._critical.popleft()
            self.queued_bytes -= len(entry.frame)
            return entry
        if self._unreported_drops:
            frame = LaggingPush(dropped=self._unreported_drops, total=self.dropped).frame()
            self._unreported_drops = 0
            return _Entry(frame, None)
        if self._normal:
            entry = self._normal.popleft()
            self.queued_bytes -= len(entry.frame)
            if entry.topic is not None and self._latest.get(entry.topic) is entry:
                del self._latest[entry.topic]
            return entry
        return None

    def _send_eagerly(self) -> bool:
        """Send what waits from ``put`` itself, while the socket takes frames at once.

        A frame then leaves in the producer's turn of the event loop, not one
        task switch later (that switch is most of a relay's latency). The first
        frame the socket cannot take at once is put back first in line for the
        writer, and so is a frame a throttle holds back. ``True`` when nothing
        is left waiting or held.
        """
        while (entry := self._next()) is not None:
            if not self._try_send(entry.frame, entry.stamp):
                # First, in its order (no longer a topic's waiting frame).
                self._critical_queue().appendleft(_Entry(entry.frame, None, entry.stamp))
                self.queued_bytes += len(entry.frame)
                return False
            if self.closed.is_set():
                return True  # the send failed: the outbox is closed
        if self._throttle:
            return False  # a frame held back by a throttle: the writer sends it when due
        self._idle.set()
        return True

    def _try_send(self, frame: Frame, stamp: float | None = None) -> bool:
        """Send ``frame`` within this call if the socket takes it at once: ``True`` when
        done (sent, or failed and the outbox closed); ``False`` when it has to wait."""
        assert self._send_nowait is not None
        try:
            sent = self._send_nowait(frame)
        except Exception as exc:
            self._fail(exc)
            return True
        if sent:
            self.sent += 1
            if stamp is not None and self._on_written is not None:
                self._on_written(stamp)
        return sent

    def _fail(self, exc: BaseException) -> None:
        self.error = exc
        log.info("outbox: send failed, writer stops: %r", exc)
        self.closed.set()
        self._idle.set()
        self._wakeup.set()

    async def _write(self) -> None:
        self._parked = False  # a writer made at its first frame was taken as parked till now
        try:
            while not self.closed.is_set():
                entry = self._next()
                if entry is None:
                    await self._wait_for_work()
                    continue
                await self._send(entry.frame)
                self.sent += 1
                if entry.stamp is not None and self._on_written is not None:
                    self._on_written(entry.stamp)
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            self._fail(exc)
        finally:
            self.closed.set()
            self._idle.set()

    async def _wait_for_work(self) -> None:
        due = self._throttle.next_due()
        if due is None:
            self._idle.set()
        self._wakeup.clear()
        self._parked = True
        try:
            if due is None:
                await self._wakeup.wait()
            else:
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(max(0.0, due - self._clock())):
                        await self._wakeup.wait()
        finally:
            self._parked = False
