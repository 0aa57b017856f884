"""Whether this server can serve: its store reached and its state loaded.

The server starts whether or not the store answers. Until the start-up work
(indexes, the state a former run left) has been done once, every call that
needs the store is answered 503 ``unavailable`` with ``Retry-After``, and
``/readyz`` says why; the work is tried again with a growing wait (0.5 s up
to ``FLEET_STORE_RETRY_MAX_S``).
"""

from __future__ import annotations

from server.errors import Unavailable


class Readiness:
    def __init__(self) -> None:
        self.loaded = False
        #: Why the server is not ready (None once it is).
        self.reason: str | None = "starting"
        self.attempts = 0

    def require(self) -> None:
        """Raise 503 until the start-up work is done."""
        if not self.loaded:
            raise Unavailable(f"the server is not ready: {self.reason}", retry_after_s=2)

    def failed(self, reason: str) -> None:
        self.attempts += 1
        self.reason = reason

    def done(self) -> None:
        self.loaded = True
        self.reason = None
