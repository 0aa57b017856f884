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

import os
import sys
from typing import Any

from rich.console import Console
from rich.text import Text

from fleet_protocol import BIDI_CONTROLS, escape_controls

__all__ = [
    "OutputClosed",
    "answer_line",
    "console",
    "errors",
    "quiet_stdout",
    "shown",
]


def shown(text: str) -> str:
    """``text`` as a terminal may show it: each control character (C0 with the line
    break and escape, DEL, C1) as its escape (``\\x1b``), each character that reorders
    the line around it (U+202A to U+202E, U+2066 to U+2069) as ``\\u202e``."""
    text = escape_controls(text)
    return BIDI_CONTROLS.sub(lambda m: f"\\u{ord(m.group()):04x}", text)


class OutputClosed(Exception):
    """Nobody reads the answer any more: stdout's reader has gone (``watch ... | head -1``).
    Not an ``OSError``, so that no handler of a lost link takes it for one."""


class _Shown(Console):
    """rich's console that shows every string it renders escaped (:func:`shown`), as
    plain text: no markup, no emoji codes."""

    def __init__(self, **options: Any) -> None:
        super().__init__(markup=False, emoji=False, **options)

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
errors = _Shown(stderr=True)  # stdout stays the answer alone (what --json scripts read)


def answer_line(text: str) -> None:
    """A line of the answer on stdout at once, shown escaped (:func:`shown`: a line
    break in it too); OutputClosed when nobody reads it any more."""
    try:
        print(shown(text), flush=True)
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
