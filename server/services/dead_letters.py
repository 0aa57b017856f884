"""What a background loop does with a record it cannot handle: log it, count it,
keep it aside, go on.

Each loop (the telemetry writer, the presence, lease and command sweeps,
retention, the journal, replica sync) handles its records one at a time. A
record that fails is logged with its id, counted in ``/metrics``
(``fleet_background_errors_total{loop=...}``) and written to the
``dead_letters`` collection with a text rendering of what it held; the loop
goes on with the next. A failure of the store itself (unreachable) is
counted but sets nothing aside: the loop tries again on its next pass.
"""

from __future__ import annotations

import logging
import reprlib
from collections.abc import Callable
from datetime import datetime
from typing import Any

from server.domain.clock import Clock
from server.errors import Unavailable
from server.storage.backends import Rejected
from server.storage.dead_letters import MAX_RAW_CHARS, DeadLettersRepo

log = logging.getLogger("fleet.background")

_RENDER = reprlib.Repr()
_RENDER.maxstring = _RENDER.maxother = MAX_RAW_CHARS
_RENDER.maxlist = _RENDER.maxdict = _RENDER.maxlevel = 10_000


def render(record: Any) -> str:
    """A text of ``record`` that any store and any JSON can hold (``repr`` escapes lone
    surrogates; big integers and non-finite floats are written as digits and words)."""
    try:
        text = _RENDER.repr(record)
    except Exception as exc:  # a record whose repr fails is still set aside
        text = f"<{type(record).__name__}: repr failed: {exc!r}>"
    return text[:MAX_RAW_CHARS]


class DeadLetters:
    def __init__(
        self,
        repo: DeadLettersRepo,
        count: Callable[[str], None],
        clock: Clock,
    ) -> None:
        self.repo = repo
        self._count = count
        self.clock = clock

    def failed(self, loop: str, error: BaseException) -> None:
        """A pass failed for a reason that is not one record's (the store is down)."""
        self._count(loop)
        log.warning("background %s: %s; it tries again", loop, error)

    async def set_aside(self, loop: str, record_id: str, error: BaseException, record: Any) -> bool:
        """Keep ``record`` aside; whether it was stored (never raises)."""
        self._count(loop)
        log.error("background %s: record %s set aside: %r", loop, record_id, error)
        doc = {
            "loop": loop,
            "record_id": record_id,
            "error": render(error),
            "raw": render(record),
            "at": self.clock(),
        }
        try:
            await self.repo.insert(doc)
        except (Unavailable, Rejected) as exc:
            log.error("background %s: record %s could not be kept aside: %r", loop, record_id, exc)
            return False
        return True

    async def of_loop(self, loop: str, limit: int) -> list[dict[str, Any]]:
        return await self.repo.of_loop(loop, limit)

    async def drop_before(self, before: datetime) -> int:
        return await self.repo.drop_before(before)
