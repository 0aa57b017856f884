"""What can go wrong on the link, sorted by what the agent does about it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from pydantic import ValidationError

from fleet_protocol import field_errors

#: What a refused token's message asks (the token comes from either).
CHECK_TOKEN = "check the token (FLEET_AGENT_TOKEN or --token)"


class AgentError(Exception):
    """Base of the agent's errors."""


class FatalError(AgentError):
    """Retrying cannot help (401, 403, bad configuration): stop with this message."""


class TokenRefused(FatalError):
    """The server refused the token itself: unknown, expired or revoked (HTTP 401, an
    ``unauthorized`` ack, a socket closed with 4401). A gateway tells its local units
    so before it stops (``UnitServer.token_refused``): a restart would not help them."""


class RetryableError(AgentError):
    """Network trouble, timeouts, 5xx, 429: back off and try again."""

    def __init__(self, message: str, retry_after_s: float | None = None) -> None:
        super().__init__(message)
        self.retry_after_s = retry_after_s


class SessionLost(RetryableError):
    """The server no longer knows the instance (404, 409 ``instance_finished``).

    The agent starts (or resumes) an instance again.
    """


class Refused(RetryableError):
    """The server refused the data as invalid (422, or an op's ``invalid``): ``fields``
    names what, with why (``params``, ``samples.3.lat``), as the error's details say."""

    def __init__(self, message: str, fields: list[tuple[str, str]]) -> None:
        super().__init__(message)
        self.fields = fields


def refused_fields(details: object) -> list[tuple[str, str]]:
    """``(field, message)`` of an error's ``details`` (a list of ``{field, message}``)."""
    if not isinstance(details, list):
        return []
    return [
        (str(d.get("field", "")), str(d.get("message", ""))) for d in details if isinstance(d, dict)
    ]


def field_errors_of(exc: ValidationError) -> list[tuple[str, str]]:
    """``(field, message)`` of each error the wire model found."""
    return [(e.field, e.message) for e in field_errors(exc)]


@dataclass(frozen=True)
class Refusal:
    """What a refused ``update_param`` blames: the samples to set aside (their seqs), and
    whether its parameters were at fault; ``reason`` in a line (the first five fields)."""

    seqs: list[int]
    params: bool
    reason: str


def refusal_of(errors: list[tuple[str, str]], batch: list[dict[str, Any]]) -> Refusal:
    """The :class:`Refusal` of ``errors`` (``(field, message)``) for the samples ``batch``
    that was sent: ``samples.3.lat`` names the fourth of them."""
    reason = "; ".join(f"{field}: {message}" for field, message in errors[:5])
    at = (_sample_index(f) for f, _ in errors)
    bad = sorted({i for i in at if i is not None and i < len(batch)})
    params = any(f.split(".")[0] == "params" for f, _ in errors)
    return Refusal([batch[i]["seq"] for i in bad], params, reason)


def _sample_index(field: str) -> int | None:
    """``3`` of ``samples.3.lat``; None for any other field."""
    parts = field.split(".")
    if len(parts) > 1 and parts[0] == "samples" and parts[1].isdigit():
        return int(parts[1])
    return None
