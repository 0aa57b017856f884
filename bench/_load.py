"""A lean HTTP/1.1 keep-alive load generator (asyncio streams), so the client is not the limit."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

RequestMaker = Callable[[int, int], bytes]  # (connection index, request number) -> bytes


def get(path: str, headers: dict[str, str] | None = None) -> bytes:
    lines = [f"GET {path} HTTP/1.1", "Host: bench"]
    lines += [f"{k}: {v}" for k, v in (headers or {}).items()]
    return ("\r\n".join(lines) + "\r\n\r\n").encode()


def post_json(path: str, body: bytes, headers: dict[str, str] | None = None) -> bytes:
    lines = [
        f"POST {path} HTTP/1.1",
        "Host: bench",
        "Content-Type: application/json",
        f"Content-Length: {len(body)}",
    ]
    lines += [f"{k}: {v}" for k, v in (headers or {}).items()]
    return ("\r\n".join(lines) + "\r\n\r\n").encode() + body


async def _one_connection(
    port: int, index: int, make: RequestMaker, deadline: float, counts: list[int], errors: list[str]
) -> None:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    n = 0
    try:
        while time.perf_counter() < deadline:
            writer.write(make(index, n))
            head = await reader.readuntil(b"\r\n\r\n")
            status = int(head[9:12])
            length = 0
            for line in head.split(b"\r\n"):
                if line[:15].lower() == b"content-length:":
                    length = int(line[15:])
            body = await reader.readexactly(length)
            if status != 200 and len(errors) < 5:
                errors.append(f"{status} {body[:200]!r}")
            n += 1
            counts[index] += 1
    finally:
        writer.close()


async def hammer(
    port: int, make: RequestMaker, *, connections: int, seconds: float
) -> tuple[float, list[str]]:
    """Requests per second over ``seconds`` with ``connections`` keep-alive connections."""
    counts = [0] * connections
    errors: list[str] = []
    started = time.perf_counter()
    deadline = started + seconds
    await asyncio.gather(
        *(_one_connection(port, i, make, deadline, counts, errors) for i in range(connections))
    )
    elapsed = time.perf_counter() - started
    return sum(counts) / elapsed, errors
