"""The calls the agent makes, whatever carries them.

``HttpTransport`` carries them over ``/upper/*`` (long poll for commands);
``WsTransport`` over ``/ws/vehicle`` (ops with the same bodies, acked; its
``get_control`` answers from the ``command`` pushes it has received);
``AutoTransport`` picks the WebSocket and falls back to HTTP.
Every method raises ``FatalError``, ``SessionLost`` or ``RetryableError``
(``vehicle_client.errors``) and nothing else.
"""

from __future__ import annotations

from typing import Protocol

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


class Transport(Protocol):
    async def start_instance(self, body: StartInstance) -> StartInstanceResult: ...

    async def finish_instance(self, instance_id: str) -> None: ...

    async def heartbeat(self, instance_id: str) -> HeartbeatResult: ...

    async def update_param(self, body: UpdateParam) -> UpdateParamResult: ...

    async def get_control(self, instance_id: str, wait_s: float) -> GetControlResult: ...

    async def update_fbmessage(self, body: UpdateFbMessage) -> UpdateFbMessageResult: ...

    async def aclose(self) -> None: ...
