"""The compute-offload example: a frame goes up, its segmentation comes back to the vehicle."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Callable
from datetime import UTC, datetime

import httpx

from examples.segmentation_worker import otsu_threshold, run, segment
from fleet_protocol.media import MediaHeader, encode_media_frame
from server.settings import Settings
from tests.factories import make_user, make_vehicle
from tests.live import call, connect, recv_until, serve


def pgm(width: int, height: int, bright: tuple[int, int, int, int]) -> bytes:
    x0, y0, x1, y1 = bright
    pixels = bytes(
        200 if x0 <= x <= x1 and y0 <= y <= y1 else 30 for y in range(height) for x in range(width)
    )
    return f"P5\n{width} {height}\n255\n".encode() + pixels


def test_segment_finds_the_bright_object() -> None:
    result = segment(pgm(40, 30, (10, 5, 19, 14)))
    assert result["bbox"] == [10, 5, 19, 14]
    assert 30 <= result["threshold"] < 200
    assert result["foreground_ratio"] == 100 / 1200


def test_otsu_on_a_flat_image_keeps_everything_background() -> None:
    assert otsu_threshold(bytes([7] * 50)) == 0


async def test_frame_round_trip_through_the_worker(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base:
        async with httpx.AsyncClient(base_url=base, timeout=10) as api:
            vid, vh = await make_vehicle(api)
            worker, wh = await make_user(api, "viewer", [vid])
        stop = asyncio.Event()
        task = asyncio.create_task(run(base, wh["Authorization"][7:], worker, vid, stop))
        try:
            async with await connect(base, "/ws/vehicle", vh["Authorization"][7:]) as car:
                result_topic = f"user/{worker}/segmentation/{vid}"
                await call(car, "subscribe", "s", topics=[result_topic])
                # the worker subscribes to the camera topic once it is up: resend until answered
                header = MediaHeader(
                    topic=f"vehicle/{vid}/camera",
                    ts=datetime.now(UTC),
                    content_type="image/x-portable-graymap",
                )
                frame = encode_media_frame(header, pgm(64, 48, (20, 10, 39, 29)))
                async with asyncio.timeout(20):
                    while True:
                        sent = time.perf_counter()
                        await car.send(frame)
                        try:
                            got = await recv_until(car, lambda f: f["op"] == "event", within_s=1)
                            break
                        except TimeoutError:
                            continue
                round_trip_ms = (time.perf_counter() - sent) * 1000
                assert got["topic"] == result_topic
                assert got["data"]["bbox"] == [20, 10, 39, 29]
                assert got["data"]["frame_ts"].startswith(header.ts.strftime("%Y-%m-%dT%H:%M"))
                print(json.dumps({"offload_round_trip_ms": round(round_trip_ms, 2)}))
        finally:
            stop.set()
            await asyncio.wait_for(task, 10)
