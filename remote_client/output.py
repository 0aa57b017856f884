"""Where ``fleetctl`` prints: answers on stdout, errors and progress on stderr.

Everything printed goes through here, and here alone text is made safe for a terminal
(:func:`shown`): much of it is what a vehicle (its parameters, a command's detail), an
operator or an admin (a zone's name) wrote, and a terminal obeys an escape sequence
rather than showing it. The two consoles escape every string they render (a table's
cells and title, a line), and take none of it for rich's markup or emoji codes (a
``[/x]`` in a parameter would otherwise fail the whole table); :func:`answer_line`
escapes the lines printed one by one. What scripts read is printed as written: JSON
(``--json``, ``export``) as ``json`` writes it, ASCII, its strings' control characters
escaped by JSON itself; a token alone on its line; ``track``'s file formats.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import stat
import sys
from collections.abc import Iterator
from typing import Any

from rich.console import Console
from rich.text import Text

from fleet_protocol.text import escape_controls, escape_unshown

__all__ = [
    "OutputClosed",
    "answer_line",
    "console",
    "errors",
    "quiet_stdout",
    "reader_watched",
    "shown",
]


def shown(text: str) -> str:
    """``text`` as a terminal may show it: each control character (C0 with the line
    break and escape, DEL, C1) as its escape (``\\x1b``), each character that reorders
    the line around it, breaks it (U+2028, U+2029) or is not seen (``fleet_protocol.text``,
    ``UNSHOWN``) as ``\\u202e``."""
    return escape_unshown(escape_controls(text))


class OutputClosed(Exception):
    """Nobody reads the answer any more: stdout's reader has gone (``watch ... | head -1``).
    Not an ``OSError``, so that no handler of a lost link takes it for one."""


class _Shown(Console):
    """rich's console that shows every string it renders escaped (:func:`shown`), as
    plain text: no markup, no emoji codes."""

    def __init__(self, **options: Any) -> None:
        super().__init__(markup=False, emoji=False, **options)
        if "width" not in options:
            # rich reads COLUMNS once, here, at import; read it (or the terminal's size)
            # when printing instead, as a resized terminal or the caller's setting has it
            self._width = None

    def render_str(self, text: str, **options: Any) -> Text:
        options.update(markup=False, emoji=False)
        return super().render_str(shown(text), **options)


class _Answers(_Shown):
    """The answers' console, whose reader going away is :class:`OutputClosed` (exit 141 in
    ``fleetctl``), as for a line printed; rich itself would exit 1, a refusal's code."""

    def on_broken_pipe(self) -> None:
        self.quiet = True
        raise OutputClosed


console = _Answers()
# stdout stays the answer alone (what --json scripts read); a message on stderr is one line
# however long (a terminal wraps it; a log or a pipe keeps it whole)
errors = _Shown(stderr=True, soft_wrap=True)


def answer_line(text: str) -> None:
    """A line of the answer on stdout at once, shown escaped (:func:`shown`: a line
    break in it too); OutputClosed when nobody reads it any more."""
    try:
        print(shown(text), flush=True)
    except BrokenPipeError:
        raise OutputClosed from None


@contextlib.contextmanager
def reader_watched() -> Iterator[None]:
    """Inside a running task: the block ends with :class:`OutputClosed` as soon as
    stdout's reader has gone, even while nothing is being written (``fleetctl watch |
    head -1`` on a quiet fleet would otherwise wait for the next change to find out).

    When stdout is a pipe, on Linux: the event loop watches it, and the kernel reports an
    error on a pipe's write end once its last reader has closed it (``EPOLLERR``). The
    task is then cancelled, and the cancellation becomes :class:`OutputClosed` here.
    Elsewhere (a terminal, a file, another system) the next line written finds out."""
    fd = _pipe_out()
    task = asyncio.current_task()
    if fd is None or task is None:
        yield
        return
    loop = asyncio.get_running_loop()
    gone = False

    def reader_gone() -> None:
        nonlocal gone
        loop.remove_reader(fd)
        gone = True
        task.cancel()

    loop.add_reader(fd, reader_gone)  # a pipe's write end is never readable: its error is
    try:
        yield
    except asyncio.CancelledError:
        if not gone:
            raise
        task.uncancel()
        raise OutputClosed from None
    finally:
        if not gone:
            loop.remove_reader(fd)


def _pipe_out() -> int | None:
    """stdout's descriptor when it is a pipe, on Linux (:func:`reader_watched`)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        fd = sys.stdout.fileno()
        return fd if stat.S_ISFIFO(os.fstat(fd).st_mode) else None
    except (AttributeError, OSError, ValueError):
        return None  # not a file (a test's capture)


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
