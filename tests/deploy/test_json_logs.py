"""The server's JSON log lines (``FLEET_LOG_FORMAT=json``, as both compose files set it):
one JSON object a line, the exception carried, and no token in any, from a record
formatted here and from a real fleet-server process."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from server.logs import REDACTED, JsonLines
from tests.agent.procs import ADMIN_TOKEN, Fleet, ServerProcess


def test_json_lines_carry_the_exception_and_no_token() -> None:
    import logging
    import sys

    from server.logs import RedactSecrets

    try:
        raise RuntimeError("refused Bearer fct_abcdefghijklmnop")
    except RuntimeError:
        record = logging.LogRecord(
            "fleet.x", logging.ERROR, __file__, 1, "failed for %s", ("?token=s3cret",),
            sys.exc_info(),
        )  # fmt: skip
    record.extra_field = {"token_url": "/ws/client?token=s3cret"}
    RedactSecrets().filter(record)
    line = json.loads(JsonLines().format(record))
    assert list(line)[:4] == ["time", "level", "logger", "message"]
    assert line["level"] == "ERROR" and line["logger"] == "fleet.x"
    assert line["message"] == f"failed for ?token={REDACTED}"
    assert "RuntimeError: refused Bearer [redacted]" in line["exception"]
    assert line["extra_field"] == {"token_url": f"/ws/client?token={REDACTED}"}
    assert "s3cret" not in json.dumps(line) and "fct_abc" not in json.dumps(line)


@pytest.mark.slow
def test_a_real_server_with_json_logs_writes_json_lines_without_tokens(tmp_path: Path) -> None:
    server = ServerProcess(tmp_path)
    server.env.update(FLEET_LOG_FORMAT="json", FLEET_LOG_LEVEL="info")
    server.start()
    ws_url = server.url.replace("http://", "ws://")
    try:
        fleet = Fleet(server)
        fleet.call("GET", "/api/vehicles")  # the admin token in a header
        vehicle_token = fleet.create_vehicle("usv-log")
        # tokens on the URL: uvicorn logs each socket's path with its query string
        with connect(f"{ws_url}/ws/client?token={ADMIN_TOKEN}") as ws:
            ws.send(json.dumps({"op": "subscribe", "id": "1", "topics": ["fleet"]}))
            assert json.loads(ws.recv(timeout=10))["op"] == "ack"
        with connect(f"{ws_url}/ws/vehicle?token={vehicle_token}") as ws:
            pass
        wrong = "fct_" + "x" * 40
        with connect(f"{ws_url}/ws/client?token={wrong}") as ws:  # accepted, then closed
            with pytest.raises(ConnectionClosed) as closed:
                ws.recv(timeout=10)
            assert closed.value.rcvd is not None and closed.value.rcvd.code == 4401
    finally:
        server.stop()
    text = server.log.read_text()
    lines = [json.loads(line) for line in text.splitlines()]  # every line is JSON
    assert lines
    for line in lines:
        assert {"time", "level", "logger", "message"} <= set(line), line
    messages = [line["message"] for line in lines]
    assert any(f"/ws/client?token={REDACTED}" in m for m in messages), messages
    assert any(f"/ws/vehicle?token={REDACTED}" in m for m in messages), messages
    for secret in (ADMIN_TOKEN, vehicle_token, wrong):
        assert secret not in text
