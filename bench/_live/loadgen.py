"""The capacity load: vehicles at 1 Hz over ``/ws/vehicle``, from several worker processes.

:class:`ProcessLoadGenerator` starts ``procs`` worker processes (``multiprocessing``,
spawn), pinned to the cores given (the bench's, not the server's), and shares the
vehicles out among them. Each worker (:mod:`bench._live.loadgen_worker`) runs its own
event loop and owns a share of the vehicles, one TCP connection and WebSocket each, on
a minimal WebSocket client (:mod:`bench._live.rawws`): it sends each vehicle's
``update_param`` once a second and times each ack. The parent asks for a window's
figures over a pipe: latencies and counters since the last window; it reads the
workers' CPU by psutil.
"""

from __future__ import annotations

import asyncio
import contextlib
import multiprocessing
from collections.abc import Sequence
from multiprocessing.connection import Connection
from typing import Any

import psutil

from bench._live.loadgen_worker import worker_main


class ProcessLoadGenerator:
    """The parent's side: workers started, vehicles shared out, windows gathered."""

    def __init__(self, ws_base: str, procs: int, cores: Sequence[int] | None) -> None:
        host_port = ws_base.split("://", 1)[1].rstrip("/")
        host, _, port = host_port.rpartition(":")
        ctx = multiprocessing.get_context("spawn")
        self.procs = []
        self.pipes: list[Connection] = []
        for _ in range(max(1, procs)):
            parent, child = ctx.Pipe()
            proc = ctx.Process(
                target=worker_main, args=(child, host, int(port), list(cores or [])), daemon=True
            )
            proc.start()
            child.close()
            self.procs.append(proc)
            self.pipes.append(parent)
        self.ps = [psutil.Process(p.pid) for p in self.procs if p.pid is not None]
        self.counts = [0] * len(self.pipes)
        self._next = 0  # the worker that gets the next vehicle

    async def _ask_all(self, messages: Sequence[Any]) -> list[Any]:
        for pipe, message in zip(self.pipes, messages, strict=True):
            if message is not None:
                pipe.send(message)
        answers = []
        for pipe, message in zip(self.pipes, messages, strict=True):
            answers.append(None if message is None else await asyncio.to_thread(pipe.recv))
        return answers

    async def add(self, pairs: Sequence[tuple[str, str]]) -> int:
        """Share the vehicles out (round robin) and open them; the failures."""
        shares: list[list[tuple[str, str]]] = [[] for _ in self.pipes]
        for pair in pairs:
            shares[self._next].append(pair)
            self._next = (self._next + 1) % len(self.pipes)
        answers = await self._ask_all([("add", s) if s else None for s in shares])
        failures = 0
        for i, answer in enumerate(answers):
            if answer is not None:  # ("added", vehicles the worker holds in all, failures)
                self.counts[i] = answer[1]
                failures += answer[2]
        return failures

    @property
    def count(self) -> int:
        """The vehicles connected, all workers together."""
        return sum(self.counts)

    async def take_window(self) -> dict[str, Any]:
        answers = await self._ask_all([("window",)] * len(self.pipes))
        out: dict[str, Any] = {"latencies": [], "sent": 0, "acked": 0, "nacks": 0, "late": 0,
                               "closed": 0, "max_tick_lag_ms": 0.0}  # fmt: skip
        for a in answers:
            out["latencies"].extend(a["latencies"])
            for key in ("sent", "acked", "nacks", "late", "closed"):
                out[key] += a[key]
            out["max_tick_lag_ms"] = max(out["max_tick_lag_ms"], a["max_tick_lag_ms"])
        return out

    def cpu_s(self) -> float:
        """The workers' CPU seconds (user + system) so far."""
        total = 0.0
        for p in self.ps:
            with contextlib.suppress(psutil.Error):
                t = p.cpu_times()
                total += t.user + t.system
        return total

    async def stop(self) -> None:
        for pipe in self.pipes:
            with contextlib.suppress(OSError):
                pipe.send(("stop",))
        for pipe in self.pipes:
            with contextlib.suppress(EOFError, OSError):
                if await asyncio.to_thread(pipe.poll, 10):
                    pipe.recv()
        for proc in self.procs:
            proc.join(5)
            if proc.is_alive():
                proc.kill()
                proc.join()
