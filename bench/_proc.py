"""Child processes for the benches: free loopback ports, pinning, start and stop."""

from __future__ import annotations

import contextlib
import os
import resource
import signal
import socket
import subprocess
import time
from collections.abc import Callable


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def raise_nofile() -> int:
    """Raise the soft limit of open files to the hard limit; the new soft limit."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < hard:
        resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
    return resource.getrlimit(resource.RLIMIT_NOFILE)[0]


def pinning() -> bool:
    """Whether there are two cores to pin to (servers on one, the bench on another)."""
    return len(os.sched_getaffinity(0)) >= 2 and (os.cpu_count() or 1) >= 2


def child_setup(core: int | None) -> Callable[[], None]:
    """A ``preexec_fn``: open-files limit raised, pinned to ``core`` if given."""

    def setup() -> None:
        raise_nofile()
        if core is not None:
            os.sched_setaffinity(0, {core})

    return setup


def wait_for_port(port: int, process: subprocess.Popen[bytes], what: str, within_s: float) -> None:
    """Until ``port`` accepts a connection; an error if ``process`` exits or time runs out."""
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        if process.poll() is not None:
            error = process.stderr.read().decode().strip() if process.stderr else ""
            raise RuntimeError(
                f"{what} exited with {process.returncode}" + (f": {error}" if error else "")
            )
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 0.2):
            return
        time.sleep(0.05)
    raise RuntimeError(f"{what} did not listen on {port} within {within_s}s")


def stop(process: subprocess.Popen[bytes], sig: int = signal.SIGTERM, within_s: float = 20) -> None:
    """Signal ``process`` and wait; killed if it is still there after ``within_s``."""
    if process.poll() is None:
        process.send_signal(sig)
        try:
            process.wait(timeout=within_s)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def rss_mb(pid: int) -> float:
    """A process's resident memory, MB."""
    import psutil

    return float(psutil.Process(pid).memory_info().rss / 2**20)
