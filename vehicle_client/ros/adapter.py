"""``--adapter ros``: the agent's side of the ROS bridge's line protocol.

Connects to the bridge (``--ros-bridge HOST:PORT``), reconnecting while it
is away, keeps the latest state and report, and writes commands. Without a
state from the bridge there is no fix, so no sample is taken.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from vehicle_client.ros import mapping
from vehicle_client.sim.simulator import TaskReport

log = logging.getLogger(__name__)

RECONNECT_S = 1.0


class RosAdapter:
    vehicle_type: str | None = None  # the registered type: the bridge does not say
    capabilities: tuple[str, ...] = ("stop", "go_to", "keep_station", "follow_path")

    def __init__(self, address: str) -> None:
        host, _, port = address.rpartition(":")
        if not host or not port.isdigit():
            raise ValueError(f"--ros-bridge must be HOST:PORT, got {address!r}")
        self.host, self.port = host, int(port)
        self._fields: dict[str, Any] | None = None
        self._local = False
        self._report: TaskReport | None = None
        self._writer: asyncio.StreamWriter | None = None
        self.connected = asyncio.Event()

    @property
    def local_control(self) -> bool:
        return self._local

    def telemetry(self) -> dict[str, Any] | None:
        return self._fields

    def report(self) -> TaskReport | None:
        return self._report

    def describe(self) -> dict[str, Any]:
        return {"adapter": "ros"}

    def _send(self, message: dict[str, Any]) -> None:
        if self._writer is None:
            raise ValueError("the ROS bridge is not connected")
        self._writer.write(mapping.encode(message))

    def execute(self, kind: str, args: dict[str, Any], command_id: str | None = None) -> None:
        self._report = None
        self._send({"op": "execute", "kind": kind, "args": args, "command_id": command_id})

    def halt(self) -> None:
        self._report = None
        if self._writer is not None:
            self._send({"op": "halt"})

    def on_line(self, message: dict[str, Any]) -> None:
        if message["op"] == "state":
            fields = message.get("fields")
            self._fields = fields if isinstance(fields, dict) else None
            self._local = bool(message.get("local_control"))
        elif message["op"] == "report":
            self._report = TaskReport(
                message.get("kind", ""),
                message.get("status", "failed"),
                message.get("progress"),
                message.get("detail"),
            )

    async def run(self) -> None:
        while True:
            try:
                reader, self._writer = await asyncio.open_connection(self.host, self.port)
            except OSError as exc:
                log.warning("ROS bridge at %s:%d: %s", self.host, self.port, exc)
                await asyncio.sleep(RECONNECT_S)
                continue
            self.connected.set()
            try:
                while line := await reader.readline():
                    message = mapping.decode(line)
                    if message is not None:
                        self.on_line(message)
            except OSError as exc:
                log.warning("ROS bridge link lost: %s", exc)
            finally:
                self.connected.clear()
                self._writer.close()
                self._writer = None
                self._fields = None
            await asyncio.sleep(RECONNECT_S)
