"""``python -m server``: the same as ``fleet-server``."""

from server.cli import main

main()
