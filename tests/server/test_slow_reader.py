"""A reader that stops reading costs the server a bounded amount of memory, given back
when it is gone (a real fleet-server process, its RSS read from /proc).

The review saw 600 frames of 1 MiB held for one slow reader and RSS going from 132 to
1,497 MiB, not given back after it closed. Now a socket's queue is bounded in bytes
(``FLEET_WS_QUEUE_BYTES``, 8 MiB): past it the socket is closed (4429) and its queue let
go."""

from __future__ import annotations

import asyncio
from pathlib import Path

import httpx
import psutil
import pytest
import websockets

from tests.agent.procs import ADMIN_TOKEN, ServerProcess
from tests.live import call

pytestmark = pytest.mark.slow

MIB = 2**20
FRAME_CHARS = 900_000  # a publish just under the 1 MiB frame bound
FRAMES = 120  # 105 MiB offered to a reader that takes none of it


def rss_mib(server: ServerProcess) -> float:
    assert server.proc is not None
    return psutil.Process(server.proc.pid).memory_info().rss / MIB


async def connections(server: ServerProcess) -> float:
    async with httpx.AsyncClient(timeout=5) as c:
        text = (await c.get(f"{server.url}/metrics")).text
    line = next(x for x in text.splitlines() if x.startswith("fleet_ws_connections"))
    return float(line.split()[-1])


async def test_a_reader_that_stops_reading_is_cut_off_and_its_memory_given_back(
    tmp_path: Path,
) -> None:
    server = ServerProcess(tmp_path)
    await asyncio.to_thread(server.start)
    try:
        url = server.url.replace("http://", "ws://") + "/ws/client"
        headers = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
        topic = "user/admin/big"
        async with websockets.connect(url, additional_headers=headers, compression=None) as warm:
            await call(warm, "subscribe", "w", topics=[topic])
        baseline = rss_mib(server)
        # The reader subscribes, then reads nothing: its client stops taking from the socket.
        reader = await websockets.connect(
            url, additional_headers=headers, compression=None, max_queue=1
        )
        await call(reader, "subscribe", "s", topics=[topic])
        peak = baseline
        async with websockets.connect(
            url, additional_headers=headers, compression=None, max_size=2 * MIB
        ) as writer:
            body = "x" * FRAME_CHARS
            for n in range(FRAMES):
                ack = await call(writer, "publish", f"p{n}", topic=topic, data=body)
                assert ack["ok"], n
                peak = max(peak, rss_mib(server))

            async def reader_gone() -> bool:
                return await connections(server) == 1  # the writer alone

            async with asyncio.timeout(20):
                while not await reader_gone():  # noqa: ASYNC110 (deadline poll)
                    await asyncio.sleep(0.1)
            after = rss_mib(server)
        await reader.close()
        assert peak - baseline < 128, (baseline, peak)  # not the 105 MiB offered, times copies
        assert after - baseline < 64, (baseline, peak, after)
        log = (tmp_path / "server.log").read_text()
        assert "Traceback" not in log, log[-2000:]
    finally:
        await asyncio.to_thread(server.stop)
