"""Where ``fleetctl`` prints: answers on stdout, errors and progress on stderr."""

from __future__ import annotations

import os
import sys

from rich.console import Console


class OutputClosed(Exception):
    """Nobody reads the answer any more: stdout's reader has gone (``watch ... | head -1``).
    Not an ``OSError``, so that no handler of a lost link takes it for one."""


class _Answers(Console):
    """rich's console, whose reader going away is :class:`OutputClosed` (exit 141 in
    ``fleetctl``), as for a line printed; rich itself would exit 1, a refusal's code."""

    def on_broken_pipe(self) -> None:
        self.quiet = True
        raise OutputClosed


console = _Answers()
errors = Console(stderr=True)  # stdout stays the answer alone (what --json scripts read)


def answer_line(text: str) -> None:
    """A line of the answer on stdout at once; OutputClosed when nobody reads it any more."""
    try:
        print(text, flush=True)
    except BrokenPipeError:
        raise OutputClosed from None


def quiet_stdout() -> None:
    """stdout to the null device, so that what is still buffered for a reader that has gone
    is dropped at exit rather than failing again (Python's advice on SIGPIPE)."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        return  # not a file (a test's capture): nothing is flushed to a pipe at exit
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, fd)
    os.close(devnull)
