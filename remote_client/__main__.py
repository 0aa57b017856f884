"""``python -m remote_client``: the same as ``fleetctl``."""

from remote_client.cli import main

if __name__ == "__main__":  # imported (a walk of the package's modules): nothing runs
    main()
