"""Two checkouts' ``update_param / trivial`` in one run: ``python -m bench._side_by_side
ROUNDS DIR...`` (each DIR a checkout of the project, ``git worktree add --detach DIR REV``,
run with this project's ``.venv``).

This machine's speed moves over seconds, and two bench runs one after the other
compare its moods as much as the code. Here each checkout's server
(``bench._serve``, as ``core_http`` starts it) is up at once, one idle while
another is loaded, and every kind of request of every server takes its turn in
short windows (the order rotated each turn), as ``core_http`` does within one
server: the ratios of a round are measured under the same conditions. Prints
each round's requests per second and ratio per checkout, then min / median /
max of the ratios.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

from bench._load import get, hammer, post_json
from bench.core_http import CONNECTIONS, TOKEN, _free_port, _update_body, _vehicles, _wait_ready

TURNS = 8
WINDOW_S = 0.4

Maker = Callable[[int, int], bytes]


def _kinds(port: int) -> dict[str, Maker]:
    units = _vehicles(port, CONNECTIONS)
    seqs = [0] * CONNECTIONS
    trivial = get("/_bench/trivial")

    def update(i: int, _: int) -> bytes:
        iid, token = units[i]
        first = seqs[i] + 1
        seqs[i] += 10
        body = _update_body(iid, first, 10)
        return post_json("/upper/update_param", body, {"Authorization": f"Bearer {token}"})

    return {"trivial": lambda i, n: trivial, "update": update}


async def _rounds(servers: dict[str, tuple[int, dict[str, Maker]]], rounds: int) -> None:
    order = [(name, kind) for name, (_, kinds) in servers.items() for kind in kinds]
    for name, kind in order:  # warm each one up
        port, kinds = servers[name]
        await hammer(port, kinds[kind], connections=CONNECTIONS, seconds=WINDOW_S)
    ratios: dict[str, list[float]] = {name: [] for name in servers}
    for _ in range(rounds):
        rates = dict.fromkeys(order, 0.0)
        for turn in range(TURNS):
            for name, kind in order[turn % len(order) :] + order[: turn % len(order)]:
                port, kinds = servers[name]
                rate, errors = await hammer(
                    port, kinds[kind], connections=CONNECTIONS, seconds=WINDOW_S
                )
                if errors:
                    raise RuntimeError(f"requests failed ({name}, {kind}): {errors}")
                rates[(name, kind)] += rate / TURNS
        said = []
        for name in servers:
            trivial, update = rates[(name, "trivial")], rates[(name, "update")]
            ratios[name].append(update / trivial)
            said.append(
                f"{name}: trivial {trivial:,.0f} update {update:,.0f} {update / trivial:.3f}"
            )
        print(" | ".join(said), flush=True)
    for name, values in ratios.items():
        low, mid, high = min(values), statistics.median(values), max(values)
        print(f"{name}: update_param / trivial min {low:.3f} median {mid:.3f} max {high:.3f}")


def main(argv: list[str]) -> None:
    if len(argv) < 2 or not argv[0].isdigit():
        raise SystemExit(__doc__)
    rounds, checkouts = int(argv[0]), [Path(d).resolve() for d in argv[1:]]
    procs: list[subprocess.Popen[bytes]] = []
    with contextlib.ExitStack() as stack:
        try:
            _serve(stack, checkouts, procs, rounds)
        finally:
            for proc in procs:
                proc.terminate()
                proc.wait(timeout=30)


def _serve(
    stack: contextlib.ExitStack,
    checkouts: list[Path],
    procs: list[subprocess.Popen[bytes]],
    rounds: int,
) -> None:
    servers: dict[str, tuple[int, dict[str, Maker]]] = {}
    for n, checkout in enumerate(checkouts, 1):
        port = _free_port()
        store = stack.enter_context(tempfile.TemporaryDirectory())
        proc = subprocess.Popen(
            [sys.executable, "-m", "bench._serve", str(port), store, TOKEN],
            cwd=checkout,
            env={**os.environ, "PYTHONPATH": str(checkout), "PYTHONUNBUFFERED": "1"},
        )
        procs.append(proc)
        _wait_ready(port, proc)
        servers[f"{n}. {checkout}"] = (port, _kinds(port))  # the same one twice: its spread
    asyncio.run(_rounds(servers, rounds))


if __name__ == "__main__":
    main(sys.argv[1:])
