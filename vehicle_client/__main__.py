"""``python -m vehicle_client``: the same as ``fleet-agent``."""

from vehicle_client.cli import main

main()
