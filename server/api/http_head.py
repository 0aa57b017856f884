"""uvicorn's HTTP protocol (httptools), with the bounds it lacks for a server on the open
network: a request's head (its line and headers) of at most :data:`MAX_HEAD_BYTES`, read
within :data:`HEAD_TIMEOUT_S` of its first byte, and a body that does not stall for
:data:`BODY_IDLE_S`.

httptools sets no limit of its own: a client with no token could send headers without end
(the server held 1.7 GB for eight such connections) or trickle a byte every few seconds and
hold a connection for ever (slowloris). Past a bound the answer is uvicorn's own for a
request it cannot read (400, ``Invalid HTTP request received.``), or the connection is
closed when the request stalls; the app then sees the client gone. A request that comes in
whole, the common case, costs a search for the end of its head and no timer.
"""

from __future__ import annotations

from asyncio import TimerHandle
from typing import Any

from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

__all__ = ["BODY_IDLE_S", "HEAD_TIMEOUT_S", "MAX_HEAD_BYTES", "BoundedHttpTools"]

#: The longest request head (request line and headers) read: as uvicorn's h11 parser
#: and the documented ~64 KB.
MAX_HEAD_BYTES = 64 * 1024
#: How long a request's head may take to come, from its first byte.
HEAD_TIMEOUT_S = 10.0
#: How long a request's body may stall (no byte coming) before the connection is closed.
BODY_IDLE_S = 30.0

_END = b"\r\n\r\n"


class BoundedHttpTools(HttpToolsProtocol):
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._head_bytes = 0  # of the request being read, while its head is not complete
        self._in_head = True
        self._in_body = False
        self._timer: TimerHandle | None = None

    def data_received(self, data: bytes) -> None:
        if self._in_head:
            end = data.find(_END)
            self._head_bytes += len(data) if end < 0 else end + len(_END)
            if self._head_bytes > MAX_HEAD_BYTES:
                self.logger.warning("a request head over %d bytes: refused", MAX_HEAD_BYTES)
                self._stop_timer()
                self.send_400_response("Invalid HTTP request received.")
                return
        elif self._in_body:
            self._stop_timer()  # it came on: the stall is counted again from now
        super().data_received(data)
        if self.transport.get_protocol() is not self:
            return  # upgraded: the connection is the WebSocket's now
        if self._timer is None and not self.transport.is_closing():
            if self._in_head and self._head_bytes:
                self._timer = self.loop.call_later(HEAD_TIMEOUT_S, self._stalled, "head")
            elif self._in_body:
                self._timer = self.loop.call_later(BODY_IDLE_S, self._stalled, "body")

    def on_headers_complete(self) -> None:
        self._in_head, self._in_body, self._head_bytes = False, True, 0
        self._stop_timer()
        super().on_headers_complete()

    def on_message_complete(self) -> None:
        self._in_head, self._in_body = True, False
        self._stop_timer()
        super().on_message_complete()

    def connection_lost(self, exc: Exception | None) -> None:
        self._stop_timer()
        super().connection_lost(exc)

    def _stop_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _stalled(self, part: str) -> None:
        self._timer = None
        if self.transport.get_protocol() is self and not self.transport.is_closing():
            self.logger.warning("a request's %s stalled: the connection is closed", part)
            self.transport.close()
