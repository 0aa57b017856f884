"""``fleetctl --help``, each group's and each command's: every summary in a list and every
paragraph of a command's help broken only where the terminal's width breaks it (one
written over two lines of its docstring was shown broken there, mid-sentence, at any
width)."""

from __future__ import annotations

import itertools
import re
from collections.abc import Iterator

import pytest
from typer.main import get_command

from remote_client.cli import app
from tests.fleetctl_run import runner

GROUPS = ["vehicles", "users", "gateways", "zones", "obstacles", "failsafe", "audit"]


def _summaries(args: list[str], columns: int) -> dict[str, list[str]]:
    """``fleetctl ARGS --help`` at ``columns``: each listed command's lines in the list."""
    shown = runner.invoke(app, [*args, "--help"], env={"COLUMNS": str(columns)})
    assert shown.exit_code == 0, shown.output
    assert max(map(len, shown.stdout.splitlines())) <= columns, shown.stdout
    listed = shown.stdout.split("─ Commands ─", 1)[1].splitlines()[1:]
    rows: dict[str, list[str]] = {}
    name = ""
    for line in listed:
        row = re.match(r"│ (\S+)?\s+(.*?)\s*│$", line)
        if row is None:
            break  # the panel's end
        name = row.group(1) or name
        rows.setdefault(name, []).append(row.group(2))
    assert rows, shown.stdout
    return rows


@pytest.mark.parametrize("group", [[], *([g] for g in GROUPS)], ids=["fleetctl", *GROUPS])
def test_each_commands_summary_is_one_line_where_the_width_allows(group: list[str]) -> None:
    for name, lines in _summaries(group, 200).items():
        assert len(lines) == 1, (name, lines)
        assert lines[0].endswith((".", ")")), (name, lines)


@pytest.mark.parametrize("group", [[], *([g] for g in GROUPS)], ids=["fleetctl", *GROUPS])
def test_at_80_columns_a_summary_breaks_only_where_the_next_word_would_not_fit(
    group: list[str],
) -> None:
    for name, lines in _summaries(group, 80).items():
        width = max(len(line) for line in lines)  # the column's width, at the least
        for line, after in itertools.pairwise(lines):
            next_word = after.split(" ", 1)[0]
            assert len(line) + 1 + len(next_word) > width - 2, (name, lines)


def _commands(command: object, path: list[str]) -> Iterator[list[str]]:
    """``path`` and the path of every command under it."""
    yield path
    for name, sub in getattr(command, "commands", {}).items():
        yield from _commands(sub, [*path, name])


@pytest.mark.parametrize("path", list(_commands(get_command(app), [])), ids=" ".join)
def test_a_commands_help_at_80_columns_breaks_a_line_only_where_the_next_word_would_not_fit(
    path: list[str],
) -> None:
    shown = runner.invoke(app, [*path, "--help"], env={"COLUMNS": "80"})
    assert shown.exit_code == 0, shown.output
    prose = shown.stdout.split("Usage:", 1)[1].split("╭", 1)[0].splitlines()[1:]
    paragraphs = "\n".join(line.strip() for line in prose).strip().split("\n\n")
    for lines in (paragraph.splitlines() for paragraph in paragraphs):
        for line, after in itertools.pairwise(lines):
            assert len(line) + 1 + len(after.split(" ", 1)[0]) > 80 - 4, lines
