"""The live sockets' two shortcuts, pure: a server frame written without websockets'
Frame object must be byte for byte what websockets would send, and an op run up to its
first wait in the read callback must finish in a task exactly as if the task had run it
all (its result, its exception, its cancellation)."""

from __future__ import annotations

import asyncio
from types import SimpleNamespace

import pytest
from websockets.frames import Frame, Opcode

from server.api.ws import _run_eagerly
from server.api.ws_direct import LiveWebSocketProtocol, _header


@pytest.mark.parametrize("size", [0, 1, 125, 126, 127, 65535, 65536, 300_000])
@pytest.mark.parametrize(("opcode", "first"), [(Opcode.TEXT, 0x81), (Opcode.BINARY, 0x82)])
def test_a_frame_header_is_what_websockets_would_send(
    size: int, opcode: Opcode, first: int
) -> None:
    payload = bytes(range(256)) * (size // 256) + bytes(size % 256)
    expected = Frame(opcode, payload).serialize(mask=False, extensions=[])
    assert _header(first, size) + payload == expected


async def test_an_op_that_never_waits_is_done_in_the_call() -> None:
    done: list[str] = []

    async def op() -> None:
        done.append("ran")

    assert _run_eagerly(op()) is None
    assert done == ["ran"]


async def test_an_op_that_waits_is_finished_by_a_task_with_what_it_waited_for() -> None:
    gate: asyncio.Future[int] = asyncio.get_running_loop().create_future()
    seen: list[object] = []

    async def op() -> None:
        seen.append("before")
        seen.append(await gate)
        await asyncio.sleep(0)  # a bare yield too
        seen.append("after")

    rest = _run_eagerly(op())
    assert rest is not None and seen == ["before"]
    task = asyncio.ensure_future(_finish(rest))
    await asyncio.sleep(0)
    assert not task.done()
    gate.set_result(7)
    await asyncio.wait_for(task, 5)
    assert seen == ["before", 7, "after"]


async def test_an_error_after_the_wait_reaches_the_task() -> None:
    gate: asyncio.Future[None] = asyncio.get_running_loop().create_future()

    async def op() -> None:
        await gate
        raise ValueError("refused")

    rest = _run_eagerly(op())
    assert rest is not None
    task = asyncio.ensure_future(_finish(rest))
    gate.set_result(None)
    with pytest.raises(ValueError, match="refused"):
        await asyncio.wait_for(task, 5)


async def test_a_cancelled_task_cancels_the_op_where_it_waits() -> None:
    gate: asyncio.Future[None] = asyncio.get_running_loop().create_future()
    cleaned: list[str] = []

    async def op() -> None:
        try:
            await gate
        finally:
            cleaned.append("finally")

    rest = _run_eagerly(op())
    assert rest is not None
    task = asyncio.ensure_future(_finish(rest))
    await asyncio.sleep(0)
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    assert cleaned == ["finally"]
    assert gate.cancelled()


async def _finish(rest: object) -> None:
    await rest  # type: ignore[misc]


class _Reader:
    """What ``LiveWebSocketProtocol._whole_frames`` reads of its protocol."""

    def __init__(self, max_size: int | None = 2**20) -> None:
        self.conn = SimpleNamespace(max_message_size=max_size)
        self.close_sent = None
        self._rank = 0
        self.got: list[tuple[object, int]] = []
        self._on_message = lambda message, rank: self.got.append((message, rank))


def _client_frame(opcode: Opcode, payload: bytes, fin: bool = True) -> bytes:
    return Frame(opcode, payload, fin).serialize(mask=True, extensions=[])


def test_whole_frames_are_handed_over_and_the_rest_left_from_a_frame_start() -> None:
    reader = _Reader()
    texts = [b'{"op":"heartbeat"}', "é".encode() * 100, b"x" * 70_000]
    whole = b"".join(_client_frame(Opcode.TEXT, t) for t in texts[:2])
    binary = _client_frame(Opcode.BINARY, b"\x00\x01")
    ping = _client_frame(Opcode.PING, b"p")
    large = _client_frame(Opcode.TEXT, texts[2])  # 64 KiB and more: the parser's
    rest = LiveWebSocketProtocol._whole_frames(reader, whole + binary + ping + large)  # type: ignore[arg-type]
    assert reader.got == [(texts[0].decode(), 1), (texts[1].decode(), 2), (b"\x00\x01", 3)]
    assert rest == ping + large


@pytest.mark.parametrize(
    "frames",
    [
        [_client_frame(Opcode.TEXT, b"first part", fin=False)],  # a fragment
        [_client_frame(Opcode.TEXT, b"cut")[:-1]],  # cut by the read
        [Frame(Opcode.TEXT, b"unmasked").serialize(mask=False, extensions=[])],
        [_client_frame(Opcode.TEXT, b"\xff\xfe")],  # not UTF-8: the parser says 1007
        [_client_frame(Opcode.CLOSE, b"\x03\xe8")],
    ],
)
def test_any_other_frame_goes_to_the_parser_untouched(frames: list[bytes]) -> None:
    reader = _Reader()
    data = b"".join(frames)
    assert LiveWebSocketProtocol._whole_frames(reader, data) == data  # type: ignore[arg-type]
    assert reader.got == []


def test_a_frame_over_the_size_limit_goes_to_the_parser() -> None:
    reader = _Reader(max_size=10)
    data = _client_frame(Opcode.TEXT, b"x" * 11)
    assert LiveWebSocketProtocol._whole_frames(reader, data) == data  # type: ignore[arg-type]
    assert reader.got == []
