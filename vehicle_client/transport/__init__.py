"""How the agent reaches the server: one interface; WebSocket first, HTTP long-poll as fallback."""

from vehicle_client.transport.auto import AutoTransport, LinkChoice
from vehicle_client.transport.base import Transport
from vehicle_client.transport.http import HttpTransport
from vehicle_client.transport.ws import WsLink, WsTransport, WsUnavailable

__all__ = [
    "AutoTransport",
    "HttpTransport",
    "LinkChoice",
    "Transport",
    "WsLink",
    "WsTransport",
    "WsUnavailable",
]
