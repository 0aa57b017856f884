"""The sending half of the vehicle WebSocket: ops out, their acks awaited, batches formed.

``OpChannel`` gives each op an ``id`` and waits for its ``ack`` (with a
timeout: a link that does not answer is broken). With ``batch_tick_s``
(gateways), ops leave as ``batch`` frames, as Nagle's algorithm does with
bytes: an op that finds no other op awaiting its ack (and no batch forming)
leaves at once, so a unit's publish on a quiet link is not held for a tick;
while some are in flight, the next ones gather for at most a tick and leave
together.

The socket is ``WsLink``'s (``vehicle_client.transport.ws``): it opens it,
reads it, hands each ``ack`` to :meth:`OpChannel.settle` and, once the socket
closed, fails the waiters with :meth:`OpChannel.fail_all`. The channel tells
the link (``broken``) when a write finds the socket closed or an ack never
comes. The frames themselves are ``vehicle_client.transport.wire``'s.
"""

from __future__ import annotations

import asyncio
import secrets
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from websockets.asyncio.client import ClientConnection
from websockets.exceptions import ConnectionClosed

from fleet_protocol.ws import AckPush
from vehicle_client.errors import AgentError, RetryableError
from vehicle_client.transport.wire import IdSource, ack_error, batches, close_error, op_frame

__all__ = ["OpChannel", "Socket"]


@dataclass
class Socket:
    """One connection of the link, and how it ended."""

    ws: ClientConnection
    error: AgentError | None = None  # set once closed: what the waiters raise
    closed: asyncio.Event = field(default_factory=asyncio.Event)


class OpChannel:
    """Ops on the link's socket, each matched to its ack; batched when ``batch_tick_s``."""

    def __init__(
        self,
        *,
        batch_tick_s: float,
        ack_timeout_s: float,
        current: Callable[[], Socket | None],
        broken: Callable[[Socket, AgentError], None],
    ) -> None:
        """``current``: the link's socket now (a batch leaves on it at the tick's end);
        ``broken``: the link's end of a socket, with what its waiters raise."""
        self.batch_tick_s = batch_tick_s
        self.ack_timeout_s = ack_timeout_s
        self._current = current
        self._broken = broken
        self._ids = IdSource(secrets.token_hex(2) + "-")
        self._pending: dict[str, tuple[asyncio.Future[AckPush], dict[str, Any]]] = {}
        self._queue: list[dict[str, Any]] = []
        self._flusher: asyncio.Task[None] | None = None
        self.frames_out = 0

    async def call(
        self, sock: Socket, op: dict[str, Any], what: str | None, *, check: bool
    ) -> AckPush:
        """Send ``op`` on ``sock`` with a fresh id; its ack (``ok: true``), or the matching
        error (``check=False``: the ack as it came, ``ok: false`` included)."""
        op = {**op, "id": self._ids.next()}
        fut: asyncio.Future[AckPush] = asyncio.get_running_loop().create_future()
        self._pending[op["id"]] = (fut, op)
        try:
            await self.send(sock, op)
            async with asyncio.timeout(self.ack_timeout_s):  # never swallows a cancel
                ack = await fut
        except TimeoutError:
            error = RetryableError(f"{op['op']}: no ack within {self.ack_timeout_s:g} s")
            self._broken(sock, error)  # a link that does not answer is broken
            _fire_close(sock)
            raise error from None
        finally:
            self._pending.pop(op["id"], None)
            if fut.done() and not fut.cancelled():
                fut.exception()  # a close set it while the send failed: told once, by that
        if check and not ack.ok:
            raise ack_error(ack, what or op["op"])
        return ack

    async def send(self, sock: Socket, op: dict[str, Any]) -> None:
        """``op`` on ``sock`` at once, or queued for the batch that is forming."""
        if self.batch_tick_s <= 0:
            await self.write(sock, op_frame(op))
            return
        flushing = self._flusher is not None and not self._flusher.done()
        own = op.get("id")
        if not flushing and not any(key != own for key in self._pending):
            await self.write(sock, op_frame(op))  # nothing else in flight: no wait
            return
        self._queue.append(op)
        if not flushing:
            self._flusher = asyncio.create_task(self._flush(), name="ws-batch")

    async def _flush(self) -> None:
        """At the tick's end: the ops queued during it, as ``batch`` frames."""
        await asyncio.sleep(self.batch_tick_s)
        queued, self._queue = self._queue, []
        sock = self._current()
        try:
            if sock is None:
                raise RetryableError("the link closed before the batch left")
            for frame in batches(queued):
                await self.write(sock, frame)
        except AgentError as exc:
            for op in queued:  # their waiters hear it now, not at their timeout
                entry = self._pending.get(op.get("id", ""))
                if entry is not None and not entry[0].done():
                    entry[0].set_exception(exc)

    async def write(self, sock: Socket, frame: str | bytes) -> None:
        """One frame on ``sock``; a socket found closed is the link's end."""
        if sock.error is not None:
            raise sock.error
        try:
            await sock.ws.send(frame)
        except ConnectionClosed as exc:
            error = close_error(exc.rcvd.code if exc.rcvd else None, None)
            self._broken(sock, error)
            raise error from None
        self.frames_out += 1

    def settle(self, ack: AckPush) -> dict[str, Any] | None:
        """Hand ``ack`` to its waiter; the op it answers, or None when its waiter gave up."""
        entry = self._pending.get(ack.id)
        if entry is None:
            return None
        fut, op = entry
        if not fut.done():
            fut.set_result(ack)
        return op

    def fail_all(self, error: AgentError) -> None:
        """The socket closed: every waiter raises ``error``, nothing queued leaves."""
        for fut, _ in self._pending.values():
            if not fut.done():
                fut.set_exception(error)
        self._pending.clear()
        self._queue.clear()

    def cancel(self) -> None:
        """The link is closing: no batch leaves."""
        if self._flusher is not None:
            self._flusher.cancel()


def _fire_close(sock: Socket) -> None:
    task = asyncio.ensure_future(sock.ws.close(1001, "no ack"))
    task.add_done_callback(lambda t: t.cancelled() or t.exception())
