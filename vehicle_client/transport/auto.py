"""WebSocket first, HTTP long-poll when the WebSocket cannot be opened.

``LinkChoice`` is the decision, shared by every vehicle of a link: a
session starts over the WebSocket unless it was refused a while ago (a proxy
that will not upgrade, a path that answers 404, a server restarting behind a
proxy); then over HTTP. The while is 5 s after the first refusal, doubling
with each refusal in a row up to ``retry_ws_s``: a server back from a restart
has its WebSocket again within seconds (a gateway's topics travel only on
it), a proxy that never upgrades is asked seldom. A session on HTTP tries to
open the WebSocket once the retry time has come (in ``get_control``): refused
again, it goes on over HTTP as it was (no new ``start_instance``, no
"resumed" in the event log each minute); open, the session ends itself
(``RetryableError``) and the next one starts over the WebSocket. A refusal
followed by HTTP failing too says nothing of the WebSocket (the server
itself is away, or a proxy before it restarting): it is taken back, so the
WebSocket is tried first again once the server answers, not a minute later.
Anything else (refused connection, 401...) is the same error on both and goes
to the agent as it is.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from fleet_protocol import (
    GetControlResult,
    HeartbeatResult,
    StartInstance,
    StartInstanceResult,
    UpdateFbMessage,
    UpdateFbMessageResult,
    UpdateParam,
    UpdateParamResult,
)
from vehicle_client.errors import RetryableError
from vehicle_client.transport.base import Transport
from vehicle_client.transport.ws import WsTransport, WsUnavailable

log = logging.getLogger(__name__)

#: Seconds on HTTP before the WebSocket is tried again: the longest wait.
RETRY_WS_S = 60.0
#: ... and the first (it doubles with each refusal in a row).
FIRST_RETRY_WS_S = 5.0


@dataclass
class LinkChoice:
    """Which way the link goes now (pure: the caller gives the clock)."""

    retry_ws_s: float = RETRY_WS_S
    clock: Callable[[], float] = time.monotonic
    refused_at: float | None = None
    reason: str = ""
    fallbacks: int = field(default=0)
    #: Refusals in a row (since the WebSocket was last open).
    refusals: int = 0

    @property
    def mode(self) -> str:
        return "http" if self.refused_at is not None else "ws"

    @property
    def wait_s(self) -> float:
        """How long after the last refusal the WebSocket is tried again."""
        doubled = FIRST_RETRY_WS_S * 2 ** min(max(self.refusals - 1, 0), 16)
        return min(self.retry_ws_s, doubled)

    def use_ws(self) -> bool:
        """Whether a session starting now tries the WebSocket."""
        if self.refused_at is None:
            return True
        return self.clock() - self.refused_at >= self.wait_s

    def refused(self, reason: str) -> None:
        self.refusals += 1
        first = self.refused_at is None
        if first:
            self.fallbacks += 1
        log.warning(
            "the WebSocket cannot be opened (%s): %s HTTP long-poll,"
            " trying the WebSocket again in %.0f s",
            reason,
            "falling back to" if first else "staying on",
            self.wait_s,
        )
        self.refused_at, self.reason = self.clock(), reason

    def unheard(self) -> None:
        """The last refusal was followed by HTTP failing too: take it back (the server was
        away, not its WebSocket), so that the next session tries the WebSocket first."""
        self.refusals = max(0, self.refusals - 1)
        if self.refusals == 0:
            self.refused_at, self.reason = None, ""

    def opened(self) -> None:
        if self.refused_at is not None:
            log.warning("the WebSocket is open again: leaving HTTP long-poll")
        self.refused_at, self.reason, self.refusals = None, "", 0


class AutoTransport:
    """One vehicle's transport: its ``WsTransport`` or the shared ``HttpTransport``."""

    def __init__(self, ws: WsTransport, http: Transport, choice: LinkChoice) -> None:
        self.ws = ws
        self.http = http
        self.choice = choice
        self._now: Transport = ws

    @property
    def kind(self) -> str:
        return "ws" if self._now is self.ws else "http"

    async def start_instance(self, body: StartInstance) -> StartInstanceResult:
        refused = False
        if self.choice.use_ws():
            try:
                res = await self.ws.start_instance(body)
            except WsUnavailable as exc:
                self.choice.refused(str(exc))
                refused = True
            else:
                self.choice.opened()
                self._now = self.ws
                return res
        self._now = self.http
        try:
            return await self.http.start_instance(body)
        except RetryableError:
            if refused:
                self.choice.unheard()
            raise

    async def _websocket_opens(self) -> bool:
        """On HTTP, the retry time come: whether the WebSocket opens now (refused: the
        wait grows, and the session goes on over HTTP)."""
        try:
            await self.ws.link.open()
        except WsUnavailable as exc:
            self.choice.refused(str(exc))
            return False
        except RetryableError:
            return False  # the server away: the long poll says so, and the session ends
        return True

    async def finish_instance(self, instance_id: str) -> None:
        await self._now.finish_instance(instance_id)

    async def heartbeat(self, instance_id: str) -> HeartbeatResult:
        return await self._now.heartbeat(instance_id)

    async def update_param(self, body: UpdateParam) -> UpdateParamResult:
        return await self._now.update_param(body)

    async def update_fbmessage(self, body: UpdateFbMessage) -> UpdateFbMessageResult:
        return await self._now.update_fbmessage(body)

    async def get_control(self, instance_id: str, wait_s: float) -> GetControlResult:
        if self._now is self.http and self.choice.use_ws() and await self._websocket_opens():
            raise RetryableError("the WebSocket opens again: the session moves to it")
        if self._now is self.http:
            # The long poll ends no later than the WebSocket's retry time.
            left = self.choice.wait_s - (self.choice.clock() - (self.choice.refused_at or 0))
            wait_s = max(0.0, min(wait_s, left))
        return await self._now.get_control(instance_id, wait_s)

    async def aclose(self) -> None:
        await self.ws.aclose()
        await self.http.aclose()
