"""Where ``fleetctl`` prints: answers on stdout, errors and progress on stderr."""

from __future__ import annotations

from rich.console import Console

console = Console()
errors = Console(stderr=True)  # stdout stays the answer alone (what --json scripts read)
