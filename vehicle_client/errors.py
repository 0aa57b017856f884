"""What can go wrong on the link, sorted by what the agent does about it."""

from __future__ import annotations


class AgentError(Exception):
    """Base of the agent's errors."""


class FatalError(AgentError):
    """Retrying cannot help (401, 403, bad configuration): stop with this message."""


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
