"""What the agent logs when an HTTP answer is not the server's error envelope."""

from __future__ import annotations

import asyncio

import httpx
import pytest

from fleet_protocol import StartInstance
from vehicle_client.errors import RetryableError
from vehicle_client.transport.http import HttpTransport

PAGE = """<!DOCTYPE HTML>
<html lang="en">
    <head>
        <title>Error response</title>
    </head>
    <body>
        <h1>Error response</h1>
        <p>Error code: 501</p>
    </body>
</html>
"""


def test_a_page_that_is_no_error_envelope_is_said_on_one_line() -> None:
    """``--server`` naming something else (a web server, a captive portal) answered with
    HTML: its lines went into the agent's log as they were, one warning over ten lines,
    at every try."""

    def page(request: httpx.Request) -> httpx.Response:
        return httpx.Response(501, text=PAGE, headers={"content-type": "text/html"})

    async def call() -> None:
        link = HttpTransport("http://127.0.0.1:9", "t", transport=httpx.MockTransport(page))
        try:
            await link.start_instance(StartInstance(vehicle_id="usv-1"))
        finally:
            await link.aclose()

    with pytest.raises(RetryableError) as raised:
        asyncio.run(call())
    said = str(raised.value)
    assert "\n" not in said
    assert said.startswith("/upper/start_instance: 501: <!DOCTYPE HTML> <html lang=")
