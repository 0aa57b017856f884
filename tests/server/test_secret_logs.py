"""No token reaches a log: a real fleet-server at log level info, a socket opened with
``?token=`` (uvicorn logs every accepted WebSocket with its path and query)."""

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
    assert redact("Authorization: Bearer abc.def-ghi") == "Authorization: Bearer [redacted]"
    assert redact("minted fct_Zx9-_aaaaaaa for ana") == "minted [redacted] for ana"
    assert redact("a plain line") == "a plain line"


@pytest.mark.slow
async def test_a_token_in_a_socket_url_is_not_written_to_the_log(tmp_path: Path) -> None:
    server = ServerProcess(tmp_path)
    server.env["FLEET_LOG_LEVEL"] = "info"
    await asyncio.to_thread(server.start)
    try:
        url = server.url.replace("http://", "ws://") + f"/ws/client?token={ADMIN_TOKEN}"
        async with websockets.connect(url) as ws:
            await ws.send(json.dumps({"op": "subscribe", "id": "s", "topics": ["fleet"]}))
            assert (await recv_until(ws, lambda f: f.get("id") == "s"))["ok"] is True
        async with websockets.connect(url.replace(ADMIN_TOKEN, "fct_wrong-token-xyz")) as ws:
            with pytest.raises(websockets.ConnectionClosed):
                await recv_until(ws, lambda f: False, within_s=10)
    finally:
        await asyncio.to_thread(server.stop)
    log = (tmp_path / "server.log").read_text()
    assert "WebSocket /ws/client?token=[redacted]" in log  # uvicorn's line, redacted
    assert ADMIN_TOKEN not in log
    assert "fct_wrong-token-xyz" not in log
