"""No token reaches a log: a real fleet-server at log level debug, a socket opened with
``?token=`` (uvicorn logs every accepted WebSocket with its path and query) and one that
sends its token in an ``auth`` frame (the protocol library would log every frame's text
at debug: it is kept from doing so, a token's key can be spelled in ways no redaction
knows)."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest
import websockets

from server.logs import redact
from tests.agent.procs import ADMIN_TOKEN, ServerProcess
from tests.live import recv_until


def test_redact_finds_tokens_in_urls_headers_and_text() -> None:
    assert redact("GET /ws/client?token=abc123&x=1") == "GET /ws/client?token=[redacted]&x=1"
    # the name as the server decodes it: %74 is "t"
    assert redact("GET /ws/client?%74oken=abc123 x") == "GET /ws/client?%74oken=[redacted] x"
    assert redact("/api/events?vehicle_id=v1&kind=zone") == "/api/events?vehicle_id=v1&kind=zone"
    assert redact("Authorization: Bearer abc.def-ghi") == "Authorization: Bearer [redacted]"
    assert redact("minted fct_Zx9-_aaaaaaa for ana") == "minted [redacted] for ana"
    assert redact("a plain line") == "a plain line"
    shortened = """< TEXT '{"op":"auth","token":"fct_hyDJxiuE3n...Eg0Hhbt5KzEh"}' [71 bytes]"""
    assert redact(shortened) == """< TEXT '{"op":"auth","token":"[redacted]"}' [71 bytes]"""


@pytest.mark.slow
async def test_a_token_in_a_socket_url_or_frame_is_not_written_to_the_log(
    tmp_path: Path,
) -> None:
    server = ServerProcess(tmp_path)
    server.env["FLEET_LOG_LEVEL"] = "debug"
    await asyncio.to_thread(server.start)
    try:
        url = server.url.replace("http://", "ws://") + f"/ws/client?token={ADMIN_TOKEN}"
        async with websockets.connect(url) as ws:
            await ws.send(json.dumps({"op": "subscribe", "id": "s", "topics": ["fleet"]}))
            assert (await recv_until(ws, lambda f: f.get("id") == "s"))["ok"] is True
        bare = url.partition("?")[0]
        async with websockets.connect(f"{bare}?%74oken={ADMIN_TOKEN}") as ws:  # "token"
            await ws.send(json.dumps({"op": "subscribe", "id": "s", "topics": ["fleet"]}))
            assert (await recv_until(ws, lambda f: f.get("id") == "s"))["ok"] is True
        async with websockets.connect(bare) as ws:
            await ws.send(json.dumps({"op": "auth", "token": ADMIN_TOKEN}))
            await ws.send(json.dumps({"op": "subscribe", "id": "s", "topics": ["fleet"]}))
            assert (await recv_until(ws, lambda f: f.get("id") == "s"))["ok"] is True
        async with websockets.connect(bare) as ws:  # the key spelled as JSON also allows
            await ws.send('{"op":"auth","tok\\u0065n" :\n' + json.dumps(ADMIN_TOKEN) + "}")
            await ws.send(json.dumps({"op": "subscribe", "id": "s", "topics": ["fleet"]}))
            assert (await recv_until(ws, lambda f: f.get("id") == "s"))["ok"] is True
        async with websockets.connect(url.replace(ADMIN_TOKEN, "fct_wrong-token-xyz")) as ws:
            with pytest.raises(websockets.ConnectionClosed):
                await recv_until(ws, lambda f: False, within_s=10)
    finally:
        await asyncio.to_thread(server.stop)
    log = (tmp_path / "server.log").read_text()
    assert "WebSocket /ws/client?token=[redacted]" in log  # uvicorn's line, redacted
    assert "WebSocket /ws/client?%74oken=[redacted]" in log
    assert '"op"' not in log  # no frame's text is logged, at debug either
    for start in range(0, len(ADMIN_TOKEN) - 8):  # nor any piece of the token
        assert ADMIN_TOKEN[start : start + 8] not in log, ADMIN_TOKEN[start : start + 8]
    assert "fct_wrong-token-xyz" not in log


@pytest.mark.slow
async def test_a_socket_asked_where_none_is_served_is_no_error_in_the_log(tmp_path: Path) -> None:
    """Anyone could write ERROR lines to the log: uvicorn called each socket refused with
    its 404 a callable that "returned without completing handshake". It is told at INFO."""
    server = ServerProcess(tmp_path)
    server.env["FLEET_LOG_LEVEL"] = "info"
    await asyncio.to_thread(server.start)
    try:
        for path in ("/ws/nope", "/ws/client/"):
            with pytest.raises(websockets.InvalidStatus) as refused:
                async with websockets.connect(server.url.replace("http", "ws") + path):
                    pass
            assert refused.value.response.status_code == 404
    finally:
        await asyncio.to_thread(server.stop)
    log = server.log.read_text()
    assert "ERROR" not in log and "without completing handshake" not in log, log
    assert log.count("INFO") and "a WebSocket refused before its handshake" in log, log
