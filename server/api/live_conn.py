"""One live link as the hub keeps it: a WebSocket's principal, outbox, bus
subscriptions, units and the instances it serves (:mod:`server.api.live_hub`)."""

from __future__ import annotations

import secrets
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field

from server.api.outbox import Outbox
from server.bus import Message, Subscription
from server.domain.access import Principal


@dataclass(eq=False)
class Connection:
    """One WebSocket: who it is, its outbox, its subscriptions and units."""

    principal: Principal
    outbox: Outbox
    close: Callable[[int, str], Awaitable[None]]
    kind: str  # "vehicle" (vehicle and gateway tokens) or "client"
    digest: str = ""  # the token's digest (its revocation closes the socket)
    id: str = field(default_factory=lambda: secrets.token_hex(8))
    subs: dict[tuple[str, str], Subscription] = field(default_factory=dict)
    #: topic -> the least ``throttle_ms`` its units asked (the gateway throttles each)
    throttle: dict[str, int] = field(default_factory=dict)
    #: topic -> the units of this connection subscribed to it (a gateway serves several),
    #: each with the ``throttle_ms`` it asked
    topic_units: dict[str, dict[str, int]] = field(default_factory=dict)
    #: unit -> the topics it registered through this connection
    produces: dict[str, set[str]] = field(default_factory=dict)
    units: set[str] = field(default_factory=set)
    instances: set[str] = field(default_factory=set)  # instances this socket serves
    buffering: dict[str, list[Message]] = field(default_factory=dict)
    closed: bool = False
