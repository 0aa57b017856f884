"""The compute-offload example: a frame goes up, its segmentation comes back to the vehicle;
a frame the worker cannot read is refused and the worker goes on."""

from __future__ import annotations

import asyncio
import json
import os
import re
import sys
import threading
import time
from collections.abc import Callable
from datetime import UTC, datetime

import httpx
import pytest

from examples.segmentation_worker import Tally, otsu_threshold, parse_pgm, run, segment, take
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


#: Frames the worker cannot segment: truncated anywhere in the header or the pixels, not
#: a P5, numbers that are not, no pixels at all.
BAD_FRAMES = [
    b"", b"P5", b"P5 10", b"P5 10 10", b"P5 10 10 255", b"P5 # a comment never ended",
    b"P5 2 2 255\nabc", b"P6 1 1 255\nx", b"P5 -1 2 255\nab", b"P5 1 1 256\nx",
    b"P5 0 0 255\n", b"P5 x 1 255\nx",
]  # fmt: skip


@pytest.mark.parametrize("frame", BAD_FRAMES)
def test_a_frame_that_is_no_pgm_is_refused_at_once(frame: bytes) -> None:
    said: list[BaseException] = []

    def parse() -> None:
        try:
            parse_pgm(frame)
        except BaseException as exc:
            said.append(exc)

    parsing = threading.Thread(target=parse, daemon=True)  # a loop that never ends stays
    parsing.start()
    parsing.join(timeout=5)
    assert not parsing.is_alive(), f"parse_pgm({frame!r}) still runs"
    assert len(said) == 1 and isinstance(said[0], ValueError), said


def test_a_refused_frame_is_counted_and_kept_aside() -> None:
    tally = Tally()
    header = MediaHeader(topic="vehicle/usv-1/camera", ts=datetime.now(UTC),
                         content_type="image/x-portable-graymap")  # fmt: skip
    bad = encode_media_frame(header, b"P5 10")
    assert take(bad, tally) is None and take(b"no header", tally) is None
    good = take(encode_media_frame(header, pgm(8, 6, (2, 2, 4, 4))), tally)
    assert good is not None and good["bbox"] == [2, 2, 4, 4]
    assert (tally.segmented, tally.refused) == (1, 2)
    assert [frame for _, frame in tally.set_aside] == [bad, b"no header"]
    assert "truncated" in tally.set_aside[0][0]


async def test_the_worker_refuses_a_truncated_frame_and_answers_the_next(
    make_settings: Callable[..., Settings],
) -> None:
    """End to end, the worker in its own process: a frame cut short in its header, then
    a good one; the good one is answered, the bad one logged as refused."""
    async with serve(make_settings()) as base:
        async with httpx.AsyncClient(base_url=base, timeout=10) as api:
            vid, vh = await make_vehicle(api)
            worker, wh = await make_user(api, "viewer", [vid])
        process = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "examples.segmentation_worker", "--server", base,
            "--token", wh["Authorization"][7:], "--user", worker, "--vehicle", vid,
            env=os.environ, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        try:
            async with await connect(base, "/ws/vehicle", vh["Authorization"][7:]) as car:
                await call(car, "subscribe", "s", topics=[f"user/{worker}/segmentation/{vid}"])
                header = MediaHeader(topic=f"vehicle/{vid}/camera", ts=datetime.now(UTC),
                                     content_type="image/x-portable-graymap")  # fmt: skip
                bad = encode_media_frame(header, b"P5 10")
                good = encode_media_frame(header, pgm(64, 48, (20, 10, 39, 29)))
                async with asyncio.timeout(30):
                    while True:  # until the worker is subscribed: each time, the bad one first
                        await car.send(bad)
                        await car.send(good)
                        try:
                            await recv_until(car, lambda f: f["op"] == "event", within_s=1)
                            break
                        except TimeoutError:
                            continue
                # Subscribed now: this bad frame reaches it for sure, and the next is answered.
                await car.send(bad)
                await car.send(good)
                got = await recv_until(car, lambda f: f["op"] == "event", within_s=20)
                assert got["data"]["bbox"] == [20, 10, 39, 29]
        finally:
            process.terminate()
            await asyncio.wait_for(process.wait(), 10)
        assert process.stderr is not None
        logged = (await process.stderr.read()).decode()
    assert re.search(r"refused \(\d+ so far\): the PGM header is truncated", logged), logged


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
