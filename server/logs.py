"""The server's logging: one set-up, and no secret in any line.

:class:`RedactSecrets` sits on every handler the server sets up, its own and
uvicorn's: a token in a URL's query (``token=...``, the name as the server decodes
it: ``%74oken=`` too), the value of an
``Authorization: Bearer`` header, a JSON ``token`` field, or anything shaped like
one of the server's tokens (``fct_...``) is replaced by ``[redacted]`` in a
record's message and arguments before the line is written (an argument that is an
object, such as the WebSocket frame the protocol libraries log at debug level, as
its text). uvicorn logs every WebSocket it accepts with its path and query string,
so a client that put its token in the URL (``?token=``) would otherwise have it
written in clear. A record's exception and stack text are redacted too.

``FLEET_LOG_FORMAT=json`` writes one JSON object per line instead (python-json-logger):
``time`` (ISO 8601, UTC), ``level``, ``logger``, ``message``, and ``exception`` or
``stack`` when the record has them. Every string in it is redacted once more as it is
written, the record's extra fields included.
"""

from __future__ import annotations

import copy
import logging
import re
from datetime import datetime
from typing import Any, Literal
from urllib.parse import unquote_plus

from pythonjsonlogger.core import RESERVED_ATTRS
from pythonjsonlogger.json import JsonFormatter

__all__ = ["REDACTED", "JsonLines", "RedactSecrets", "log_config", "redact"]

REDACTED = "[redacted]"
_SECRETS = (
    # a JSON field (a socket's ``auth`` frame, a login's answer), even when the logger
    # shortened the frame in the middle of its value
    re.compile(r"(?i)(\"(?:access_)?token\"\s*:\s*\")[^\"]*"),
    re.compile(r"(?i)(\btoken=)[^&\s\"'#]+"),
    re.compile(r"(?i)(\bbearer\s+)[^\s\"',;]+"),
    re.compile(r"()\bfct_[A-Za-z0-9_-]{6,}"),
)


#: A URL query's parameter, ``name=value`` (after ``?`` or ``&``).
_QUERY_PARAM = re.compile(r"(?<=[?&])([^=&\s\"'#?]+)=([^&\s\"'#]*)")


def redact(text: str) -> str:
    """``text`` with every secret it holds replaced by ``[redacted]``."""
    if "=" in text:
        text = _QUERY_PARAM.sub(_query_param, text)
    for pattern in _SECRETS:
        text = pattern.sub(lambda m: m.group(1) + REDACTED, text)
    return text


def _query_param(found: re.Match[str]) -> str:
    """A query parameter whose name, as the server decodes it (``%74oken`` is ``token``),
    names a token: its value redacted."""
    name = found.group(1)
    if "token" in unquote_plus(name).casefold() and found.group(2):
        return f"{name}={REDACTED}"
    return found.group(0)


class RedactSecrets(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.msg, str):
            record.msg = redact(record.msg)
        if isinstance(record.args, tuple):
            record.args = tuple(_redact_arg(a) for a in record.args)
        elif isinstance(record.args, dict):
            record.args = {k: _redact_arg(v) for k, v in record.args.items()}
        if record.exc_info and not record.exc_text:
            # Formatters write exc_text when it is set (the text one), or format exc_info
            # again (the JSON one, which redacts what it writes).
            record.exc_text = _EXCEPTIONS.formatException(record.exc_info)
        if record.exc_text:
            record.exc_text = redact(record.exc_text)
        if record.stack_info:
            record.stack_info = redact(record.stack_info)
        return True


_EXCEPTIONS = logging.Formatter()


class RefusedHandshakes(logging.Filter):
    """uvicorn logs ``ASGI callable returned without completing handshake.`` at ERROR for
    every WebSocket the app refuses with an HTTP answer (``websocket.http.response``: a
    404 in the envelope for a path that serves no socket), which any client may ask for.
    The app completes or refuses every handshake it is given, so that line is such a
    refusal: told at INFO, as an answer to a client's mistake, never as a server error."""

    MESSAGE = "ASGI callable returned without completing handshake."

    def filter(self, record: logging.LogRecord) -> bool:
        if record.msg == self.MESSAGE and record.levelno == logging.ERROR:
            record.levelno, record.levelname = logging.INFO, "INFO"
            record.msg = "a WebSocket refused before its handshake (answered over HTTP)"
            return record.levelno >= logging.getLogger(record.name).getEffectiveLevel()
        return True


def _redact_arg(value: Any) -> Any:
    """A string redacted; a number as it is (a formatter may want one: ``%d``); anything
    else as its text, redacted (its ``str`` is what ``%s`` would have written)."""
    if isinstance(value, str):
        return redact(value)
    if value is None or isinstance(value, int | float):
        return value
    return redact(str(value))


def _redact_all(value: Any) -> Any:
    if isinstance(value, str):
        return redact(value)
    if isinstance(value, dict):
        return {k: _redact_all(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_redact_all(v) for v in value]
    return value


def _as_text(value: Any) -> str:
    """What the JSON encoder writes for a value it cannot encode itself."""
    return redact(str(value))


class JsonLines(JsonFormatter):
    """One JSON object per line: time, level, logger, message (and exception, stack)."""

    def __init__(self) -> None:
        super().__init__(
            ["levelname", "name", "message"],
            rename_fields={
                "levelname": "level",
                "name": "logger",
                "exc_info": "exception",
                "stack_info": "stack",
            },
            timestamp="time",
            # uvicorn adds a coloured copy of some messages; it would repeat them
            reserved_attrs=[*RESERVED_ATTRS, "color_message"],
            json_default=_as_text,
        )

    def process_log_record(self, log_data: dict[str, Any]) -> dict[str, Any]:
        at = log_data.pop("time", None)
        time = at.isoformat(timespec="milliseconds") if isinstance(at, datetime) else at
        return {"time": time, **_redact_all(log_data)}


def log_config(level: str, fmt: Literal["text", "json"] = "text") -> dict[str, Any]:
    """The ``logging.config`` dictionary of the server (uvicorn's, with the filter on every
    handler, and the server's own loggers on a handler of their own); ``fmt="json"``: every
    handler writes :class:`JsonLines`."""
    from uvicorn.config import LOGGING_CONFIG

    config: dict[str, Any] = copy.deepcopy(LOGGING_CONFIG)
    config["filters"] = {
        "redact": {"()": RedactSecrets},
        "refused_handshakes": {"()": RefusedHandshakes},
    }
    config["formatters"]["fleet"] = {"format": "%(asctime)s %(levelname)s %(name)s: %(message)s"}
    config["handlers"]["fleet"] = {
        "class": "logging.StreamHandler",
        "formatter": "fleet",
        "stream": "ext://sys.stderr",
    }
    if fmt == "json":
        config["formatters"]["json"] = {"()": JsonLines}
    for handler in config["handlers"].values():
        handler["filters"] = ["redact"]
        if fmt == "json":
            handler["formatter"] = "json"
    config["root"] = {"handlers": ["fleet"], "level": level.upper()}
    for logger in config["loggers"].values():
        logger["level"] = level.upper()
    config["loggers"]["uvicorn.error"]["filters"] = ["refused_handshakes"]
    return config
