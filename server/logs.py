"""The server's logging: one set-up, and no secret in any line.

:class:`RedactSecrets` sits on every handler the server sets up, its own and
uvicorn's: a token in a URL's query (``token=...``), the value of an
``Authorization: Bearer`` header, or anything shaped like one of the server's
tokens (``fct_...``) is replaced by ``[redacted]`` in a record's message and
arguments before the line is written. uvicorn logs every WebSocket it accepts
with its path and query string, so a client that put its token in the URL
(``?token=``) would otherwise have it written in clear.
"""

from __future__ import annotations

import copy
import logging
import re
from typing import Any

__all__ = ["REDACTED", "RedactSecrets", "log_config", "redact"]

REDACTED = "[redacted]"
_SECRETS = (
    re.compile(r"(?i)(\btoken=)[^&\s\"'#]+"),
    re.compile(r"(?i)(\bbearer\s+)[^\s\"',;]+"),
    re.compile(r"()\bfct_[A-Za-z0-9_-]{6,}"),
)


def redact(text: str) -> str:
    """``text`` with every secret it holds replaced by ``[redacted]``."""
    for pattern in _SECRETS:
        text = pattern.sub(lambda m: m.group(1) + REDACTED, text)
    return text


class RedactSecrets(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.msg, str):
            record.msg = redact(record.msg)
        if isinstance(record.args, tuple):
            record.args = tuple(redact(a) if isinstance(a, str) else a for a in record.args)
        elif isinstance(record.args, dict):
            record.args = {
                k: redact(v) if isinstance(v, str) else v for k, v in record.args.items()
            }
        return True


def log_config(level: str) -> dict[str, Any]:
    """The ``logging.config`` dictionary of the server (uvicorn's, with the filter on every
    handler, and the server's own loggers on a handler of their own)."""
    from uvicorn.config import LOGGING_CONFIG

    config: dict[str, Any] = copy.deepcopy(LOGGING_CONFIG)
    config["filters"] = {"redact": {"()": RedactSecrets}}
    config["formatters"]["fleet"] = {"format": "%(asctime)s %(levelname)s %(name)s: %(message)s"}
    config["handlers"]["fleet"] = {
        "class": "logging.StreamHandler",
        "formatter": "fleet",
        "stream": "ext://sys.stderr",
    }
    for handler in config["handlers"].values():
        handler["filters"] = ["redact"]
    config["root"] = {"handlers": ["fleet"], "level": level.upper()}
    for logger in config["loggers"].values():
        logger["level"] = level.upper()
    return config
