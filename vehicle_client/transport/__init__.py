"""How the agent reaches the server: one interface, HTTP now, WebSocket later."""

from vehicle_client.transport.base import Transport
from vehicle_client.transport.http import HttpTransport

__all__ = ["HttpTransport", "Transport"]
