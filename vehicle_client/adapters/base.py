"""The adapter interface between the agent and a vehicle."""

from __future__ import annotations

from typing import Any, Protocol

from vehicle_client.sim.simulator import TaskReport


class Adapter(Protocol):
    #: Command types the vehicle executes (``stop`` is always among them).
    capabilities: tuple[str, ...]
    #: The hull's type to announce (``usv``, ``auv``, ...); ``None``: the registered one.
    vehicle_type: str | None

    def telemetry(self) -> dict[str, Any] | None:
        """The latest state as sample fields (``lat``, ``lon``, ...); ``None`` without a fix."""

    def execute(self, kind: str, args: dict[str, Any], command_id: str | None = None) -> None:
        """Start a task, replacing the current one (``ValueError`` if it cannot)."""

    def halt(self) -> None:
        """Drop the current task at once."""

    def report(self) -> TaskReport | None:
        """How the current (or just finished) task stands."""

    @property
    def local_control(self) -> bool:
        """True while a person drives the vehicle from its local controls."""

    def describe(self) -> dict[str, Any]:
        """Static facts sent as the instance's initial ``params``."""

    async def run(self) -> None:
        """Keep the vehicle side going until cancelled."""
