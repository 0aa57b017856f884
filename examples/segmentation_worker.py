"""Compute offload (the multilayer paper's cloud segmentation): a processing worker.

It runs anywhere with a user token, subscribes to a vehicle's camera topic
(binary media frames: a JSON header line, then a PGM image), segments each
frame (Otsu threshold: the bright foreground against the water), and
publishes the result under ``user/<its username>/segmentation/<vehicle>``,
where the vehicle (or an operator) subscribes to it. The result carries the
frame's ``ts`` so the vehicle can measure the round trip. A frame it cannot read
(not a PGM, truncated) is refused: logged, counted, the latest few kept aside
(:class:`Tally`), and the worker goes on with the next.

    python examples/segmentation_worker.py --server http://127.0.0.1:8000 \\
        --token "$WORKER_TOKEN" --user worker --vehicle usv-1
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import websockets

from fleet_protocol.media import decode_media_frame

log = logging.getLogger("segmentation-worker")

#: How many of the latest refused frames the worker keeps aside for a look.
SET_ASIDE = 16


def parse_pgm(data: bytes) -> tuple[int, int, bytes]:
    """Width, height and pixels of a binary PGM (P5, 8 bit); ValueError for anything
    else, a truncated or malformed frame among them (each step of the header is bounded
    by the frame's end)."""
    fields: list[bytes] = []
    pos, size = 0, len(data)
    while len(fields) < 4:
        while pos < size and data[pos : pos + 1].isspace():
            pos += 1
        if pos == size:
            raise ValueError("the PGM header is truncated")
        if data[pos : pos + 1] == b"#":  # a comment, to the end of its line
            pos = data.find(b"\n", pos)
            if pos < 0:
                raise ValueError("the PGM header is truncated")
            pos += 1
            continue
        end = pos
        while end < size and not data[end : end + 1].isspace():
            end += 1
        fields.append(data[pos:end])
        pos = end
    magic, numbers = fields[0], fields[1:]
    if magic != b"P5" or not all(n.isdigit() for n in numbers):
        raise ValueError("only 8-bit binary PGM (P5) frames are segmented")
    width, height, maxval = (int(n) for n in numbers)
    if not 1 <= maxval <= 255:
        raise ValueError("only 8-bit binary PGM (P5) frames are segmented")
    if width == 0 or height == 0:
        raise ValueError("the PGM frame has no pixels")
    pixels = data[pos + 1 : pos + 1 + width * height]
    if len(pixels) != width * height:
        raise ValueError("the PGM frame is truncated")
    return width, height, pixels


def otsu_threshold(pixels: bytes) -> int:
    """The grey level that best splits the histogram into two classes."""
    histogram = [0] * 256
    for value in pixels:
        histogram[value] += 1
    total = len(pixels)
    weighted_sum = sum(i * n for i, n in enumerate(histogram))
    background = background_sum = 0
    best, best_variance = 0, -1.0
    for level in range(256):
        background += histogram[level]
        if background == 0:
            continue
        foreground = total - background
        if foreground == 0:
            break
        background_sum += level * histogram[level]
        mean_b = background_sum / background
        mean_f = (weighted_sum - background_sum) / foreground
        variance = background * foreground * (mean_b - mean_f) ** 2
        if variance > best_variance:
            best, best_variance = level, variance
    return best


def segment(frame: bytes) -> dict[str, Any]:
    """Threshold, foreground share and bounding box of one PGM frame."""
    width, height, pixels = parse_pgm(frame)
    threshold = otsu_threshold(pixels)
    xs: list[int] = []
    ys: list[int] = []
    for index, value in enumerate(pixels):
        if value > threshold:
            ys.append(index // width)
            xs.append(index % width)
    bbox = [min(xs), min(ys), max(xs), max(ys)] if xs else None
    return {
        "width": width,
        "height": height,
        "threshold": threshold,
        "foreground_ratio": len(xs) / (width * height),
        "bbox": bbox,
    }


@dataclass
class Tally:
    """What the worker did with the frames: how many it segmented, how many it refused,
    and the latest refused ones (why, and the frame's bytes), kept aside."""

    segmented: int = 0
    refused: int = 0
    set_aside: deque[tuple[str, bytes]] = field(default_factory=lambda: deque(maxlen=SET_ASIDE))


def take(frame: bytes, tally: Tally) -> dict[str, Any] | None:
    """The result to publish for one binary frame, or None when the frame is refused
    (logged, counted and kept aside in ``tally``): one bad frame never stops the worker."""
    when = "?"
    try:
        header, image = decode_media_frame(frame)
        when = header.ts.isoformat().replace("+00:00", "Z")
        result = segment(image)
    except Exception as exc:  # whatever a frame holds, the next one is taken
        tally.refused += 1
        tally.set_aside.append((str(exc), frame))
        log.warning("frame of %s refused (%d so far): %s", when, tally.refused, exc)
        return None
    tally.segmented += 1
    result["frame_ts"] = when
    return result


async def run(
    server: str, token: str, user: str, vehicle: str, stop: asyncio.Event | None = None
) -> Tally:
    """Segment the vehicle's frames until ``stop`` is set; what it did with them."""
    tally = Tally()
    url = server.replace("http", "ws", 1).rstrip("/") + "/ws/client"
    source = f"vehicle/{vehicle}/camera"
    target = f"user/{user}/segmentation/{vehicle}"
    async with websockets.connect(
        url,
        compression=None,
        max_size=16 * 2**20,
        additional_headers={"Authorization": f"Bearer {token}"},
    ) as ws:
        await ws.send(json.dumps({"op": "register", "id": "r", "topics": [target]}))
        await ws.send(json.dumps({"op": "subscribe", "id": "s", "topics": [source]}))
        log.info("segmenting %s into %s", source, target)
        while stop is None or not stop.is_set():
            try:
                frame = await asyncio.wait_for(ws.recv(), 0.5)
            except TimeoutError:
                continue
            if isinstance(frame, str):
                message = json.loads(frame)
                if message.get("op") in ("error", "ack") and message.get("ok") is False:
                    log.error("server refused: %s", message)
                continue
            result = take(frame, tally)
            if result is not None:
                await ws.send(json.dumps({"op": "publish", "topic": target, "data": result}))
    return tally


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--server", default="http://127.0.0.1:8000")
    parser.add_argument("--token", required=True, help="a user token (viewer of the vehicle)")
    parser.add_argument("--user", required=True, help="the token's username")
    parser.add_argument("--vehicle", required=True)
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO)
    with contextlib.suppress(KeyboardInterrupt):  # Ctrl-C stops it, quietly
        asyncio.run(run(args.server, args.token, args.user, args.vehicle))


if __name__ == "__main__":
    main()
