"""The topics the server alone writes, and their current state for a new subscriber.

``fleet`` (presence), ``vehicle/<id>/control``, ``vehicle/<id>/commands``,
``vehicle/<id>/events`` and ``vehicle/<id>/telemetry``: the services report
what changed through their listeners, and each change becomes an event on
the bus (built only when someone may listen). See docs/live.md for the shape
of each topic's data.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from datetime import datetime
from typing import Any

from fleet_protocol import format_ts
from server.bus import Bus
from server.domain.access import Principal
from server.services.commands import CommandService
from server.services.control import ControlService
from server.services.events import EventService
from server.services.fleet import FleetViews
from server.services.instances import InstanceService, InstanceState

RECENT_EVENTS = 20


class ServerTopics:
    def __init__(
        self,
        bus: Bus,
        instances: InstanceService,
        commands: CommandService,
        control: ControlService,
        events: EventService,
        views: FleetViews,
        fire: Callable[[Awaitable[Any]], None],
    ) -> None:
        self.bus = bus
        self.instances = instances
        self.commands = commands
        self.control = control
        self.events = events
        self.views = views
        self._fire = fire
        instances.presence_listeners.append(self._on_presence)
        control.change_listeners.append(self._on_control)
        events.subscribe(self._on_event)

    def emit(self, topic: str, data: Any) -> None:
        """An event on a topic the server writes, to every subscriber on every replica."""
        if not self.bus.remote and not self.bus.has_local(topic):
            return  # one process and nobody listening: nothing to build
        message = {
            "op": "event",
            "topic": topic,
            "data": data() if callable(data) else data,
            "ts": format_ts(self.instances.clock()),
        }
        pending = self.bus.publish_here_first(topic, message)
        if pending is not None:
            self._fire(pending)

    def _on_presence(self, state: InstanceState, presence: str) -> None:
        view = self.views.live_view(state).model_dump(mode="json")
        self.emit("fleet", {"vehicles": [view]})

    def _on_control(self, instance_id: str, vehicle_id: str, info: dict[str, Any] | None) -> None:
        data = {"instance_id": instance_id, "control": _jsonable(info)}
        self.emit(f"vehicle/{vehicle_id}/control", data)

    def _on_event(self, doc: dict[str, Any]) -> None:
        vehicle_id = doc.get("vehicle_id")
        if not vehicle_id:
            return
        event = _jsonable(doc)
        self.emit(f"vehicle/{vehicle_id}/events", {"events": [event]})
        if doc["kind"] == "command":
            self.emit(f"vehicle/{vehicle_id}/commands", {"commands": [event["data"]]})

    def telemetry(self, vehicle_id: str, samples: list[Any], replayed: list[bool]) -> None:
        topic = f"vehicle/{vehicle_id}/telemetry"
        if not self.bus.remote and not self.bus.has_local(topic):
            return
        for sample, late in zip(samples, replayed, strict=True):

            def data(sample: Any = sample, late: bool = late) -> dict[str, Any]:
                out: dict[str, Any] = sample.model_dump(mode="json", exclude_none=True)
                if late:
                    out["replayed"] = True
                return out

            self.emit(topic, data)

    async def snapshot(self, principal: Principal, topic: str) -> Any:
        """The current state of a server topic, sent first after a subscribe."""
        if topic == "fleet":
            views = await self.views.vehicles(principal)
            return {"vehicles": [v.model_dump(mode="json") for v in views]}
        parts = topic.split("/")
        if len(parts) != 3 or parts[0] != "vehicle":
            return None
        vehicle_id, kind = parts[1], parts[2]
        state = await self.instances.current_or_latest(vehicle_id)
        if kind == "telemetry":
            return state.position_json() if state is not None and state.position else None
        if kind == "control":
            info = self.control.lease_info(state.instance_id) if state is not None else None
            return {
                "instance_id": state.instance_id if state else None,
                "control": info.model_dump(mode="json") if info else None,
            }
        if kind == "commands":
            if state is None:
                return {"commands": []}
            _, recent = await self.commands.recent(principal, state.instance_id)
            return {"commands": [_jsonable(c.wire()) for c in recent]}
        if kind == "events":
            docs = await self.events.query(
                principal, vehicle_id=vehicle_id, kind=None, start=None, end=None, limit=10_000
            )
            return {"events": [_jsonable(d) for d in docs[-RECENT_EVENTS:]]}
        return None


def _jsonable(value: Any) -> Any:
    """Datetimes in the contract's format, recursively; the rest as it is."""
    if isinstance(value, datetime):
        return format_ts(value)
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    return value
