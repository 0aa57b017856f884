"""The simulator as an adapter: physics stepped in real time, ``time_scale`` times faster."""

from __future__ import annotations

import asyncio
from typing import Any

from vehicle_client.sim.dynamics import Current, VehicleParams
from vehicle_client.sim.simulator import CAPABILITIES, Simulator, TaskReport

#: How often the physics runs, per second of wall time.
STEP_HZ = 10.0


class SimAdapter:
    vehicle_type: str | None = None  # the registered type: a simulator drives any hull
    capabilities: tuple[str, ...] = CAPABILITIES

    def __init__(
        self,
        lat: float,
        lon: float,
        *,
        time_scale: float = 1.0,
        params: VehicleParams | None = None,
        current: Current | None = None,
    ) -> None:
        if time_scale <= 0:
            raise ValueError("time_scale must be positive")
        self.sim = Simulator(lat, lon, params=params, current=current)
        self.time_scale = time_scale

    @property
    def local_control(self) -> bool:
        return False

    def telemetry(self) -> dict[str, Any]:
        return self.sim.telemetry()

    def execute(self, kind: str, args: dict[str, Any], command_id: str | None = None) -> None:
        self.sim.start(self.sim.task_for(kind, args))

    def halt(self) -> None:
        self.sim.clear()

    def report(self) -> TaskReport | None:
        return self.sim.last_report

    def describe(self) -> dict[str, Any]:
        p = self.sim.params
        return {
            "adapter": "sim",
            "max_speed_mps": p.max_speed_mps,
            "time_scale": self.time_scale,
            "current_mps": [self.sim.current.east_mps, self.sim.current.north_mps],
        }

    async def run(self) -> None:
        loop = asyncio.get_running_loop()
        last = loop.time()
        while True:
            await asyncio.sleep(1.0 / STEP_HZ)
            now = loop.time()
            self.sim.step((now - last) * self.time_scale)
            last = now
