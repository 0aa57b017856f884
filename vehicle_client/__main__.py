"""``python -m vehicle_client``: the same as ``fleet-agent``."""

from vehicle_client.cli import main

if __name__ == "__main__":  # imported (a walk of the package's modules): nothing runs
    main()
