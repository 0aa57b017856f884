"""The collision forecast, run every ``FLEET_FORECAST_EVERY_S`` by one replica for all.

Every online vehicle with a reported speed and heading is projected
``FLEET_FORECAST_S`` ahead (:mod:`server.domain.forecast`); two forecast to come within
``FLEET_SEPARATION_M`` raise a ``collision_risk`` event on each of the two vehicles
(live on their events topics), once while the risk lasts: it is raised again only after
a pass without it. The replica holding the ``forecast`` lock does the work (the lock
lasts a few passes and is renewed by each), so the events are not doubled by replicas.
"""

from __future__ import annotations

import secrets
from datetime import timedelta

from server.domain.clock import Clock
from server.domain.forecast import Course, Risk, forecast
from server.services.events import EventService
from server.services.instances import InstanceService
from server.settings import Settings
from server.storage.locks import LocksRepo

#: The lock lasts this many passes: another replica takes over if this one stops.
_LOCK_PASSES = 3


class CollisionForecast:
    def __init__(
        self,
        settings: Settings,
        instances: InstanceService,
        events: EventService,
        locks: LocksRepo,
        clock: Clock,
    ) -> None:
        self.settings = settings
        self.instances = instances
        self.events = events
        self.locks = locks
        self.clock = clock
        self.replica = secrets.token_hex(6)
        #: The pairs at risk in the last pass: (vehicle, vehicle) -> instance ids.
        self.at_risk: dict[tuple[str, str], Risk] = {}

    @property
    def enabled(self) -> bool:
        return self.settings.forecast_s > 0 and self.settings.separation_m > 0

    async def tick(self) -> None:
        if not self.enabled:
            return
        now = self.clock()
        until = now + timedelta(seconds=self.settings.forecast_every_s * _LOCK_PASSES)
        if not await self.locks.hold("forecast", self.replica, now, until):
            self.at_risk.clear()  # another replica forecasts (and raises the events)
            return
        instance_of: dict[str, str] = {}
        courses = []
        for vehicle_id, instance_id, p in await self.instances.online_positions():
            speed, heading = p.get("speed_mps"), p.get("heading_deg")
            if speed is None or heading is None:
                continue
            instance_of[vehicle_id] = instance_id
            courses.append(
                Course(vehicle_id, float(p["lat"]), float(p["lon"]), float(speed), float(heading))
            )
        risks = forecast(courses, self.settings.forecast_s, self.settings.separation_m)
        current = {(r.a, r.b): r for r in risks}
        for pair, risk in current.items():
            if pair not in self.at_risk:
                await self._raise(risk, instance_of)
        self.at_risk = current

    async def _raise(self, risk: Risk, instance_of: dict[str, str]) -> None:
        for me, other in ((risk.a, risk.b), (risk.b, risk.a)):
            await self.events.record(
                "collision_risk",
                vehicle_id=me,
                instance_id=instance_of[me],
                data={
                    "other_vehicle_id": other,
                    "other_instance_id": instance_of[other],
                    "in_s": round(risk.in_s, 1),
                    "closest_m": round(risk.closest_m, 1),
                    "distance_now_m": round(risk.distance_now_m, 1),
                    "separation_m": self.settings.separation_m,
                    "lat": risk.where[0],
                    "lon": risk.where[1],
                },
            )
