"""``python -m remote_client``: the same as ``fleetctl``."""

from remote_client.cli import main

main()
