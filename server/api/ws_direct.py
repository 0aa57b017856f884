"""uvicorn's WebSocket protocol with a direct path for the live sockets' frames.

ASGI hands each frame to the app through a queue: the protocol puts a
``websocket.receive`` message, pauses reading, and the app's task wakes up
one turn of the event loop later to take it and resume reading. For a relay
that is most of its time per message. With this protocol (``fleet-server``
runs uvicorn with it), an app that finds :data:`DIRECT` among the scope's
``extensions`` may call ``attach(on_message)``: from then on each complete
text (``str``) or binary (``bytes``) message is passed to
``on_message(message, rank)`` as it is parsed, within the protocol's
``data_received``; ``rank`` counts the messages of that one read from 1 (a
read can carry thousands of small messages, and an app may want to let the
other sockets have their turn). Everything else is
uvicorn's own: the handshake, sending, closing (``websocket.disconnect``
still arrives through ``receive``), pings, flow control.

``attach`` returns the messages that were already queued, for the app to
handle first. ``pause()`` and ``resume()`` stop and restart reading from the
socket, for an app whose handling of a message has to wait.

Keepalive pings are the server's :class:`~server.api.keepalive.KeepaliveWheel`
(one timer for all its sockets, no ping to a socket its peer is talking on),
not a timer pair per socket: every ``ws_ping_interval`` an idle socket is
pinged, and one whose ping is unanswered an interval later is closed (1011;
the interval stands for ``ws_ping_timeout`` too).
``send_nowait(message)`` writes a text or binary message at once when the
transport is not asking the writer to wait, and says whether it did (the
socket's outbox sends the rest through ``send`` as usual); ``abort()`` drops
the connection at once. Without the
extension (another server, Starlette's test client) the app uses ``receive``
and ``send`` as usual.

This builds on uvicorn's sans-I/O protocol class, whose attributes are not a
public API: ``pyproject.toml`` pins uvicorn to the minor version these tests
ran with.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from typing import Any

from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol
from websockets.frames import Frame, apply_mask
from websockets.http11 import Request
from websockets.protocol import State

from server.api.http_head import BoundedHttpTools
from server.api.keepalive import KeepaliveWheel
from server.api.outbox import LazyEvent

__all__ = ["DIRECT", "LiveWebSocketProtocol", "Message"]

#: The scope extension's key.
DIRECT = "fleet.websocket.direct"

Message = str | bytes

log = logging.getLogger("fleet.ws")

#: The attribute of uvicorn's ``Config`` (one per server) that holds its wheel.
_WHEEL = "_fleet_keepalive_wheel"


class LiveWebSocketProtocol(WebSocketsSansIOProtocol):
    """:class:`WebSocketsSansIOProtocol` offering the :data:`DIRECT` extension."""

    _on_message: Callable[[Message, int], None] | None = None
    _on_ping: Callable[[], None] | None = None  # a ping from the peer: contact (API.md)
    _rank = 0  # messages handed over from the current read

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        # The WebSocket library's debug lines hold each frame's text: an auth frame's token
        # in any spelling JSON allows (``"tok\u0065n"``) no redaction can know. Never
        # written, whatever the log level (the server logs what it does with each op).
        self.conn.debug = False
        # Less held per socket (10,000 of them): the events make their waiter queues at
        # their first wait, and the unbounded queue of ASGI messages, whose ``put`` never
        # waits, keeps no queue of waiting putters (624 bytes each, 4 per socket).
        self.writable = LazyEvent()
        self.writable.set()
        queue: Any = self.queue
        if queue.maxsize <= 0 and not queue._putters:
            queue._putters = ()
            queue._finished = LazyEvent()
            queue._finished.set()

    def handle_connect(self, event: Request) -> None:
        super().handle_connect(event)
        scope = getattr(self, "scope", None)  # set when the handshake goes on to the app
        if scope is not None:
            scope["extensions"][DIRECT] = {
                "attach": self._attach,
                "pause": self._pause,
                "resume": self._resume,
                "send_nowait": self._send_nowait,
                "abort": self._abort,
                "on_ping": self._set_on_ping,
            }

    def _set_on_ping(self, callback: Callable[[], None]) -> None:
        self._on_ping = callback

    def handle_ping(self) -> None:
        super().handle_ping()  # the pong
        if self._on_ping is not None:
            self._on_ping()

    def _attach(self, on_message: Callable[[Message, int], None]) -> list[Message]:
        pending: list[Message] = []
        others: list[Any] = []
        while not self.queue.empty():
            message = self.queue.get_nowait()
            if message["type"] != "websocket.receive":
                others.append(message)
                continue
            text = message.get("text")
            pending.append(text if text is not None else bytes(message.get("bytes") or b""))
        for message in others:  # a disconnect stays for receive()
            self.queue.put_nowait(message)
        self._on_message = on_message
        self._resume()
        return pending

    def _pause(self) -> None:
        if not self.read_paused and not self.transport.is_closing():
            self.read_paused = True
            self.transport.pause_reading()

    def _resume(self) -> None:
        if self.read_paused and not self.transport.is_closing():
            self.read_paused = False
            self.transport.resume_reading()

    def _send_nowait(self, message: Message) -> bool:
        if (
            not self.handshake_complete
            or self.close_sent
            or not self.writable.is_set()
            or self.transport.is_closing()
        ):
            return False
        conn = self.conn
        payload = message.encode() if isinstance(message, str) else message
        if conn.state is State.OPEN and not (
            conn.extensions or conn.expect_continuation_frame or conn.writes
        ):
            # The frame a server sends (one, unmasked, no extension) written as is: what
            # websockets' send_text would build, without its Frame object per message.
            opcode = 0x81 if isinstance(message, str) else 0x82
            self.transport.write(_header(opcode, len(payload)) + payload)
            return True
        if isinstance(message, str):
            conn.send_text(payload)
        else:
            conn.send_binary(payload)
        self.transport.write(b"".join(conn.data_to_send()))
        return True

    def _abort(self) -> None:
        """Drop the connection at once, unsent data and all (a reader that does not read
        would hold a closing handshake up for ever)."""
        if not self.transport.is_closing():
            self.transport.abort()

    # ---- keepalive (server/api/keepalive.py) -----------------------------------------
    _heard = False  # bytes from the peer since the wheel's last visit

    def start_keepalive(self) -> None:
        if self.ping_interval is not None and self.ping_interval > 0:
            self._wheel().add(self)

    def stop_keepalive(self) -> None:
        wheel = getattr(self.config, _WHEEL, None)
        if wheel is not None:
            wheel.discard(self)
        super().stop_keepalive()

    def _wheel(self) -> KeepaliveWheel:
        wheel = getattr(self.config, _WHEEL, None)
        if wheel is None or wheel.loop is not self.loop:
            assert self.ping_interval is not None
            wheel = KeepaliveWheel(self.loop, self.ping_interval)
            setattr(self.config, _WHEEL, wheel)
        return wheel

    def handle_pong(self, event: Frame) -> None:
        if self.pending_ping_payload is None or bytes(event.data) != self.pending_ping_payload:
            return  # unsolicited, or the answer to an older ping
        self.last_ping_rtt = self.loop.time() - self.ping_sent_at
        self.pending_ping_payload = None
        self._heard = False  # a pong alone is no traffic: an idle socket is pinged each time

    def ping_due(self) -> bool:
        return self.pending_ping_payload is not None

    def heard_since(self) -> bool:
        heard, self._heard = self._heard, False
        return heard

    def send_ping(self) -> None:
        if self.close_sent or self.transport.is_closing():
            return
        self.pending_ping_payload = os.urandom(4)
        self.ping_sent_at = self.loop.time()
        self.conn.send_ping(self.pending_ping_payload)
        self.transport.write(b"".join(self.conn.data_to_send()))

    def ping_lost(self) -> None:
        log.info("a WebSocket peer did not answer a ping in %.0f s: closed", self.ping_interval)
        self.keepalive_timeout()

    # ---- reading -------------------------------------------------------------------------
    def data_received(self, data: bytes) -> None:
        self._heard = True
        self._rank = 0
        conn = self.conn
        if (
            self._on_message is not None
            and conn.state is State.OPEN
            and conn.current_size is None
            and not conn.reader.buffer
            and not conn.extensions
        ):
            # websockets' parser waits at a frame's start with nothing buffered: whole
            # frames of one message each are read here; from the first frame that is
            # anything else (a control frame, a part, a frame cut by the read) on, the
            # bytes go to the parser, which finds itself where it was.
            data = self._whole_frames(data)
            if not data:
                return
        super().data_received(data)

    def _whole_frames(self, data: bytes) -> bytes:
        """Hand over each whole, masked, unfragmented text or binary frame at the start of
        ``data`` as websockets would (RFC 6455 5.2); what is left, from a frame's start."""
        limit = self.conn.max_message_size
        end, size = 0, len(data)
        while size - end >= 6 and self._on_message is not None and not self.close_sent:
            start = end
            first, second = data[start], data[start + 1]
            length = second & 0x7F
            if first not in (0x81, 0x82) or not second & 0x80 or length == 127:
                break  # not FIN + text/binary, not masked, or 64 KiB and more: the parser
            head = start + 2
            if length == 126:
                length = int.from_bytes(data[head : head + 2], "big")
                head += 2
            end = head + 4 + length
            if end > size or (limit is not None and length > limit):
                end = start
                break
            payload = apply_mask(data[head + 4 : end], data[head : head + 4])
            if first == 0x81:
                try:
                    message: Message = payload.decode()
                except UnicodeDecodeError:
                    end = start  # to the parser, then closed with 1007 (_not_utf8)
                    break
            else:
                message = payload
            self._rank += 1
            self._on_message(message, self._rank)
        return data[end:] if end else data

    def send_receive_event_to_app(self) -> None:
        """A whole message: to ``on_message`` once attached, to uvicorn's queue before. Text
        that is not UTF-8 closes the socket here (:meth:`_not_utf8`), on either path."""
        on_message = self._on_message
        if self.close_sent:
            super().send_receive_event_to_app()  # uvicorn drops it
            return
        data = self.frames[0] if len(self.frames) == 1 else b"".join(self.frames)
        message: Message
        if self.curr_msg_data_type == "text":
            try:
                message = data.decode()
            except UnicodeDecodeError:
                self.frames = []
                self._not_utf8()
                return
        elif on_message is not None:
            message = bytes(data)
        if on_message is None:
            super().send_receive_event_to_app()  # decodes it again: the few before attach
            return
        self.frames = []
        self._rank += 1
        on_message(message, self._rank)

    def _not_utf8(self) -> None:
        """A text message that is not UTF-8 fails the connection with 1007 (RFC 6455 8.1),
        with one INFO line. uvicorn's own path logs an ERROR and its traceback for each
        (two chained, once this class had tried): any client could write them at will."""
        peer = f"{self.client[0]}:{self.client[1]}" if self.client else "peer"
        log.info("WebSocket %s sent text that is not UTF-8: closed with 1007", peer)
        self.conn.fail(1007, "text frame not UTF-8")
        self.handle_parser_exception()  # the app told (disconnect), the close sent


def _header(first: int, length: int) -> bytes:
    """A server frame's header (RFC 6455 5.2): FIN and opcode, then the length."""
    if length < 126:
        return bytes((first, length))
    if length < 65536:
        return bytes((first, 126)) + length.to_bytes(2, "big")
    return bytes((first, 127)) + length.to_bytes(8, "big")


def uvicorn_ws_options() -> dict[str, Any]:
    """The protocol options of every uvicorn that serves the app (the server, the demo,
    the tests): this WebSocket protocol, and no permessage-deflate (it costs ~7 ms per
    64 KiB round trip, and media frames are compressed already); HTTP with the bounds of
    :mod:`server.api.http_head`."""
    return {"ws": LiveWebSocketProtocol, "ws_per_message_deflate": False, "http": BoundedHttpTools}
