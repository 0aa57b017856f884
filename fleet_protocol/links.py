"""The WebSocket links' addresses and close codes, as the contract (API.md) fixes them."""

from __future__ import annotations

from urllib.parse import urlsplit

__all__ = [
    "CLOSE_FORBIDDEN",
    "CLOSE_RECONNECT",
    "CLOSE_REPLACED",
    "CLOSE_TOO_BIG",
    "CLOSE_TOO_SLOW",
    "CLOSE_TRY_AGAIN",
    "CLOSE_UNAUTHORIZED",
    "MAX_BINARY_FRAME_BYTES",
    "MAX_TEXT_FRAME_BYTES",
    "server_root_problem",
    "shown_url",
    "websocket_url",
]

#: The default bounds of one frame (the server's ``FLEET_WS_MAX_TEXT_BYTES`` and
#: ``FLEET_WS_MAX_BINARY_BYTES``; a gateway holds its units to the same).
MAX_TEXT_FRAME_BYTES = 2**20
MAX_BINARY_FRAME_BYTES = 4 * 2**20

#: The token is missing, unknown, expired or revoked.
CLOSE_UNAUTHORIZED = 4401
#: The token may not use this socket (a user token on ``/ws/vehicle``, ...).
CLOSE_FORBIDDEN = 4403
#: Another connection took this vehicle's link.
CLOSE_REPLACED = 4409
#: The token still stands, but what its user may see or do changed (an admin changed the
#: user's role or vehicles): connect again, and subscribe again under the new rights.
CLOSE_RECONNECT = 4012
#: The server cannot check the token now (its store is down): try again later.
CLOSE_TRY_AGAIN = 1013
#: A frame over the server's size bound (RFC 6455: message too big).
CLOSE_TOO_BIG = 1009
#: The client read too slowly: more than the server's ``FLEET_WS_QUEUE_BYTES`` waited for
#: it. Reconnect, and subscribe to less (or with ``throttle_ms``).
CLOSE_TOO_SLOW = 4429


def websocket_url(server: str, path: str) -> str:
    """``http://host:port/prefix`` -> ``ws://host:port/prefix<path>`` (https -> wss; a
    ws(s) URL is kept). ``ValueError`` for any other scheme."""
    if server.startswith("https://"):
        base = "wss://" + server.removeprefix("https://")
    elif server.startswith("http://"):
        base = "ws://" + server.removeprefix("http://")
    elif server.startswith(("ws://", "wss://")):
        base = server
    else:
        raise ValueError(f"the server must be an http(s) URL, got {server!r}")
    return base.rstrip("/") + path


def server_root_problem(value: str) -> str | None:
    """Why ``value`` is not a server's root URL (``http://127.0.0.1:8000``, or one behind
    a proxy's path prefix), in words that end ", not <value>" (its password hidden);
    None when it is one. Without a scheme it was taken for a server out of reach; ending
    in ``/api`` every call asked for ``/api/api/...`` and was answered 404; a user name
    or password in it was sent to no one (the token is what signs in) and shown in logs
    and errors wherever the URL is."""
    if "://" not in value:
        return f"a URL with its scheme: give http://{value}, not {value!r}"
    url = urlsplit(value)
    if url.scheme not in ("http", "https") or not url.hostname:
        example = "http://127.0.0.1:8000"
        return f"an http:// or https:// URL with a host ({example}), not {shown_url(value)!r}"
    if url.username is not None or url.password is not None:
        bare = url._replace(netloc=url.netloc.rpartition("@")[2]).geturl()
        return (
            "a URL without a user name or password (the token is what signs in, and the "
            f"URL is shown in logs): give {bare}, not {shown_url(value)!r}"
        )
    if url.path.rstrip("/").endswith("/api"):
        root = value.rstrip("/").removesuffix("/api")
        return f"the server's address, without /api: give {root}, not {value!r}"
    return None


def shown_url(value: str) -> str:
    """``value`` with whatever stands before an ``@`` in its host part replaced by
    ``***`` (a user name and password never reach a log or an error)."""
    scheme, sep, rest = value.partition("://")
    if not sep:
        return value
    netloc, slash, path = rest.partition("/")
    if "@" not in netloc:
        return value
    return f"{scheme}://***@{netloc.rpartition('@')[2]}{slash}{path}"
