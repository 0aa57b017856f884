"""``python -m server``: the same as ``fleet-server``."""

from server.cli import main

if __name__ == "__main__":  # imported (a walk of the package's modules): nothing runs
    main()
