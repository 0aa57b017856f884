"""Who may connect to the gateway's socket for local units: the connection's query read.

A unit connects to ``/?vehicle_id=<id>[&unit=<name>]``. Both are identifiers, each
given at most once; ``unit=`` with no name is refused, not taken for an unnamed
unit. The vehicle must be one the gateway's token acts for (when the server has
said which). :func:`admit` says who connects, or why the connection is closed;
:func:`listen_address`, where the socket listens.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from urllib.parse import parse_qs, urlsplit

from fleet_protocol.common import ID_PATTERN, ID_RULE
from fleet_protocol.links import CLOSE_FORBIDDEN
from vehicle_client.errors import FatalError

CLOSE_BAD_REQUEST = 4400  # the gateway's own: a unit that did not name its vehicle (or
# named itself with what is not an identifier)


@dataclass(frozen=True, slots=True)
class Admitted:
    vehicle_id: str
    name: str | None  # None: an unnamed unit (a new one each connection)


@dataclass(frozen=True, slots=True)
class Refused:
    code: int
    reason: str


def admit(path: str, acts_for: frozenset[str] | set[str] | None) -> Admitted | Refused:
    """The unit that ``path`` (the request's path and query) names, or the refusal."""
    query = parse_qs(urlsplit(path).query, keep_blank_values=True)
    if twice := next((k for k in ("vehicle_id", "unit") if len(query.get(k, ())) > 1), None):
        return Refused(CLOSE_BAD_REQUEST, f"{twice} is given more than once: give it once")
    vehicle_id = (query.get("vehicle_id") or [""])[0]
    name = query["unit"][0] if "unit" in query else None  # unit= (empty) is refused
    if not vehicle_id:
        return Refused(CLOSE_BAD_REQUEST, "connect with ?vehicle_id=<the unit's vehicle>")
    if not re.fullmatch(ID_PATTERN, vehicle_id):
        return Refused(CLOSE_BAD_REQUEST, f"vehicle_id: not a vehicle id ({ID_RULE})")
    if name is not None and not re.fullmatch(ID_PATTERN, name):
        return Refused(CLOSE_BAD_REQUEST, f"unit: not a unit name ({ID_RULE})")
    if acts_for is not None and vehicle_id not in acts_for:
        return Refused(CLOSE_FORBIDDEN, not_listed(vehicle_id))
    return Admitted(vehicle_id, name)


def listen_address(listen: str) -> tuple[str, int]:
    """``HOST:PORT`` (``:PORT``: on loopback) of the gateway's ``listen`` setting."""
    host, _, port = listen.rpartition(":")
    try:
        return host or "127.0.0.1", int(port)
    except ValueError:
        raise FatalError(f"listen must be HOST:PORT, got {listen!r}") from None


def not_listed(vehicle_id: str) -> str:
    return f"this gateway's token does not act for {vehicle_id}"
