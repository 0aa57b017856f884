"""Bodies and frames a careless or hostile client sends: a real uvicorn serving the app.

An over-size body is 413, chunked or not; an over-size frame closes the socket with
1009, a text frame that is not UTF-8 with 1007 (one INFO line in the log); a malformed
frame gets an error in the contract's envelope and the socket goes on (never 1011);
every frame counts toward the socket's rate, the malformed ones too."""

from __future__ import annotations

import asyncio
import json
import logging
from collections.abc import AsyncIterator, Callable

import httpx
import pytest
import websockets

from server.settings import Settings
from tests.factories import ADMIN, ADMIN_TOKEN
from tests.live import call, connect, recv_until, serve
from tests.server.test_ws_keepalive import RawSocket, raw_client

pytestmark = pytest.mark.usefixtures("store_backend")


@pytest.fixture
async def base(make_settings: Callable[..., Settings]) -> AsyncIterator[str]:
    settings = make_settings(max_body_bytes=4096, ws_max_text_bytes=65_536, ws_ops_per_s=20)
    async with serve(settings) as url:
        yield url


async def chunks(total: int, size: int = 1024) -> AsyncIterator[bytes]:
    """A JSON body sent chunked (no Content-Length)."""
    body = json.dumps({"vehicle_id": "usv-big", "name": "x" * total}).encode()
    for i in range(0, len(body), size):
        yield body[i : i + size]


async def test_a_chunked_body_over_the_bound_is_413(base: str) -> None:
    headers = {**ADMIN, "content-type": "application/json"}
    async with httpx.AsyncClient(base_url=base, timeout=10) as api:
        r = await api.post("/api/vehicles", headers=headers, content=chunks(10_000))
        assert r.status_code == 413, r.text
        assert r.json()["error"]["code"] == "too_large"
        r = await api.post("/api/vehicles", headers=headers, content=chunks(100))
        assert r.status_code == 201, r.text  # under the bound, chunked: served as usual


async def test_an_over_size_frame_closes_the_socket_with_1009(base: str) -> None:
    async with await connect(base, "/ws/client", ADMIN_TOKEN) as ws:
        await ws.send(json.dumps({"op": "publish", "topic": "user/admin/x", "data": "y" * 70_000}))
        with pytest.raises(websockets.ConnectionClosed):
            await recv_until(ws, lambda f: False, within_s=10)
        assert ws.close_code == 1009


async def test_a_frame_nested_1000_deep_is_an_error_not_1011(base: str) -> None:
    deep = "[" * 1000 + "]" * 1000
    async with await connect(base, "/ws/client", ADMIN_TOKEN) as ws:
        await ws.send('{"op": "publish", "id": "d", "topic": "user/admin/x", "data": ' + deep + "}")
        reply = await recv_until(ws, lambda f: f.get("id") == "d" or f["op"] == "error")
        assert reply.get("ok") is False or reply["op"] == "error", reply
        assert set(reply["error"]) >= {"code", "message"}
        assert (await call(ws, "subscribe", "s", topics=["fleet"]))["ok"] is True  # goes on


async def test_a_frame_nested_too_deep_is_refused_as_such_not_as_bad_json(base: str) -> None:
    """Valid JSON nested past what the frame reader goes is refused saying so (in an
    unknown field too), not as "not valid JSON"; bad JSON still says that."""
    async with await connect(base, "/ws/client", ADMIN_TOKEN) as ws:
        for depth, op_id in ((5000, None), (300, "u"), (1200, "n1200"), (5000, "deep")):
            deep = "[" * depth + "]" * depth
            head = '{"op": "subscribe", ' + (f'"id": "{op_id}", ' if op_id else "")
            await ws.send(head + '"topics": ["fleet"], "x": ' + deep + "}")
            reply = await recv_until(ws, lambda f: f["op"] in ("error", "ack"))
            assert reply.get("id") == op_id and reply.get("ok") in (None, False), reply
            assert "nested too deep" in reply["error"]["message"], reply
            assert "32 levels" in reply["error"]["message"], reply
        await ws.send('{"op": "subscribe", "topics": ["fleet"')
        reply = await recv_until(ws, lambda f: f["op"] == "error")
        assert reply["error"]["message"] == "the frame is not valid JSON"
        assert reply["error"]["details"] == [
            {"field": "frame", "message": "the frame is not valid JSON"}
        ]
        assert (await call(ws, "subscribe", "s", topics=["fleet"]))["ok"] is True  # goes on


async def test_an_id_past_a_part_nested_too_deep_is_still_acked(base: str) -> None:
    """The id read from the frame's text when no reader takes it whole: at its end too."""
    deep = "[" * 1500 + "]" * 1500
    async with await connect(base, "/ws/client", ADMIN_TOKEN) as ws:
        await ws.send('{"op": "publish", "topic": "user/admin/x", "data": ' + deep + ', "id": "z"}')
        reply = await recv_until(ws, lambda f: f["op"] in ("error", "ack"))
        assert reply["op"] == "ack" and reply["id"] == "z" and reply["ok"] is False, reply
        assert "nested too deep" in reply["error"]["message"], reply


async def test_a_frame_after_a_byte_order_mark_is_read_as_a_body_is(base: str) -> None:
    async with await connect(base, "/ws/client", ADMIN_TOKEN) as ws:
        await ws.send('\ufeff{"op": "subscribe", "id": "bom", "topics": ["fleet"]}')
        reply = await recv_until(ws, lambda f: f.get("id") == "bom" or f["op"] == "error")
        assert reply["op"] == "ack" and reply["ok"] is True, reply


async def test_every_frame_counts_toward_the_rate_malformed_ones_too(base: str) -> None:
    async with await connect(base, "/ws/client", ADMIN_TOKEN) as ws:
        for _ in range(60):  # three times the rate of 20 a second, at once
            await ws.send("this is not json")
        codes = []
        for _ in range(60):
            reply = await recv_until(ws, lambda f: f["op"] == "error")
            codes.append(reply["error"]["code"])
        assert "rate_limited" in codes and codes.count("rate_limited") >= 30, codes
        assert codes[0] == "invalid"  # within the rate: told what was wrong


async def closed_with(ws: RawSocket) -> tuple[int, str]:
    """The code and reason of the server's close frame, by a deadline."""
    async with asyncio.timeout(10):
        payload = await ws.until(0x8, answer=True)
    return int.from_bytes(payload[:2], "big"), payload[2:].decode()


async def test_a_text_frame_that_is_not_utf8_closes_with_1007_and_one_quiet_line(
    base: str, caplog: pytest.LogCaptureFixture
) -> None:
    """RFC 6455 8.1. Each one used to log an ERROR with two chained tracebacks (the direct
    path's decode, then uvicorn's, which it fell back on): any client could write them
    into the server's log at will. Client libraries refuse to send such a frame: a raw
    socket sends it whole once its socket is served (the direct path), in two parts (the
    parser), and before its token (uvicorn's queue, the socket waiting for ``auth``)."""
    # caplog hears uvicorn's loggers too (pytest attaches it to those that do not propagate)
    caplog.set_level(logging.INFO, logger="fleet")
    for parts in ([b'{"op":"subscribe","id":"\xff\xfe"}'], [b'{"id":"\xe2\x82', b'"}']):
        async with raw_client(base) as ws:
            ws.send(0x1, b'{"op":"subscribe","id":"s","topics":["fleet"]}')
            async with asyncio.timeout(10):
                assert b'"id":"s","ok":true' in await ws.until(0x1, answer=True)
            for n, part in enumerate(parts):
                ws.send(0x1 if n == 0 else 0x0, part, fin=n == len(parts) - 1)
            assert await closed_with(ws) == (1007, "text frame not UTF-8")
    async with raw_client(base, token=None) as ws:
        ws.send(0x1, b"\xc3\x28")
        assert await closed_with(ws) == (1007, "text frame not UTF-8")
    assert [r for r in caplog.records if r.levelno >= logging.ERROR or r.exc_info] == []
    said = [r.getMessage() for r in caplog.records if "UTF-8" in r.getMessage()]
    assert len(said) == 3 and all("closed with 1007" in line for line in said), said
    assert all(r.levelno == logging.INFO for r in caplog.records if "UTF-8" in r.getMessage())
    assert not any(ADMIN_TOKEN in r.getMessage() for r in caplog.records)
