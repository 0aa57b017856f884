"""The topics the server alone writes, and their current state for a new subscriber.

``fleet`` (presence), ``vehicle/<id>/control``, ``vehicle/<id>/commands``,
``vehicle/<id>/events`` and ``vehicle/<id>/telemetry``: the handlers here
turn the domain events the services emit into events on the bus (built only
when someone may listen), so that a socket on any replica hears them. See
docs/live.md for the shape of each topic's data.
"""

from __future__ import annotations

from collections.abc import Awaitable
from datetime import datetime
from typing import Any

from fleet_protocol import format_ts
from server.bus import Bus
from server.domain.access import Principal
from server.domain.events import (
    CommandMoved,
    ControlChanged,
    EventRecorded,
    LinkChanged,
    PresenceChanged,
    SamplesStored,
)
from server.services.commands import CommandService
from server.services.control import ControlService
from server.services.events import EventService
from server.services.fleet import FleetViews
from server.services.instances import InstanceService, InstanceState

RECENT_EVENTS = 20
#: Events after which a vehicle's alarms (``VehicleView.alarms``) are not what they were.
_ALARM_EVENTS = frozenset(
    {
        "zone_breach",
        "zone_cleared",
        "low_battery",
        "battery_recovered",
        "low_battery_cleared",
        "control_mode",
    }
)


class ServerTopics:
    def __init__(
        self,
        bus: Bus,
        instances: InstanceService,
        commands: CommandService,
        control: ControlService,
        events: EventService,
        views: FleetViews,
    ) -> None:
        self.bus = bus
        self.instances = instances
        self.commands = commands
        self.control = control
        self.events = events
        self.views = views

    def emit(self, topic: str, data: Any) -> Awaitable[None] | None:
        """An event on a topic the server writes, to every subscriber on every replica:
        delivered here within the call; what is left to await (the other replicas)."""
        if not self.bus.remote and not self.bus.has_local(topic):
            return None  # one process and nobody listening: nothing to build
        message = {
            "op": "event",
            "topic": topic,
            "data": data() if callable(data) else data,
            "ts": format_ts(self.instances.clock()),
        }
        return self.bus.publish_here_first(topic, message)

    # ---- handlers of the services' events (registered by the container) ---------
    def on_presence(self, event: PresenceChanged) -> Awaitable[None] | None:
        state = self.instances.current_by_id(event.instance_id)
        if state is None:
            view: dict[str, Any] = {
                "vehicle_id": event.vehicle_id,
                "instance_id": event.instance_id,
                "presence": event.presence,
                "alarms": [],  # nothing is known of a vehicle without an instance here
            }
        else:
            view = self.views.live_view(state, alarms=False)  # presence alone moved
            view["presence"] = event.presence
        return self.emit("fleet", {"vehicles": [view]})

    def on_link(self, event: LinkChanged) -> Awaitable[None] | None:
        """A vehicle's link delay moved: its view on ``fleet`` again (built only when
        someone may listen)."""
        return self._view_again(event.instance_id)

    def on_control(self, event: ControlChanged) -> Awaitable[None] | None:
        data = {"instance_id": event.instance_id, "control": _jsonable(event.control)}
        return self.emit(f"vehicle/{event.vehicle_id}/control", data)

    def on_event(self, event: EventRecorded) -> Awaitable[None] | None:
        doc = event.doc
        vehicle_id = doc.get("vehicle_id")
        if not vehicle_id:
            if doc["kind"] == "zones_changed":  # the fleet's record of it: on ``zones``
                data = doc.get("data") or {}
                said = {k: data.get(k) for k in ("zone_id", "action", "version")}
                return self.emit("zones", said)
            if doc["kind"] == "obstacles_changed":  # the planner's shapes: on ``zones`` too
                data = doc.get("data") or {}
                return self.emit("zones", {k: data.get(k) for k in ("obstacle_id", "action")})
            return None
        entry = _jsonable(doc)
        first = self.emit(f"vehicle/{vehicle_id}/events", {"events": [entry]})
        if doc["kind"] == "command":
            second = self.emit(f"vehicle/{vehicle_id}/commands", {"commands": [entry["data"]]})
        elif doc["kind"] in _ALARM_EVENTS:  # the vehicle's alarms moved: its view again
            second = self._stored_view_again(doc.get("instance_id"))
        elif doc["kind"] == "vehicle_changed":  # its new name or type, on the fleet's views
            data = doc.get("data") or {}
            view = {"vehicle_id": vehicle_id}
            view.update((k, data[k]) for k in ("name", "vehicle_type") if k in data)
            second = self.emit("fleet", {"vehicles": [view]})
        else:
            return first
        return None if first is None and second is None else _both(first, second)

    def _stored_view_again(self, instance_id: str | None) -> Awaitable[None] | None:
        """The vehicle's view on ``fleet``, its alarms as stored (whichever replica took
        the positions that moved them); read only when someone may listen."""
        state = self.instances.current_by_id(instance_id) if instance_id else None
        if state is None or (not self.bus.remote and not self.bus.has_local("fleet")):
            return None
        return self._emit_stored(state)

    async def _emit_stored(self, state: InstanceState) -> None:
        view = await self.views.stored_view(state)
        rest = self.emit("fleet", {"vehicles": [view]})
        if rest is not None:
            await rest

    def _view_again(self, instance_id: str | None) -> Awaitable[None] | None:
        state = self.instances.current_by_id(instance_id) if instance_id else None
        if state is None:
            return None
        return self.emit("fleet", lambda: {"vehicles": [self.views.live_view(state)]})

    def on_command_moved(self, event: CommandMoved) -> Awaitable[None] | None:
        """A step between a command's start and its end (those two come as events)."""
        moved = {
            "command_id": event.command_id,
            "type": event.type,
            "status": event.status,
            "detail": event.detail,
            "progress": event.progress,
            "issued_by": event.issued_by,
        }
        return self.emit(f"vehicle/{event.vehicle_id}/commands", {"commands": [moved]})

    def on_samples(self, event: SamplesStored) -> Awaitable[None] | None:
        topic = f"vehicle/{event.vehicle_id}/telemetry"
        if not self.bus.remote and not self.bus.has_local(topic):
            return None
        pending = []
        bound = event.ahead_after
        for sample, late in zip(event.samples, event.replayed, strict=True):

            def data(sample: dict[str, Any] = sample, late: bool = late) -> dict[str, Any]:
                # The stored form (no nulls; ``data`` JSON already): only ``ts`` to format.
                out = {**sample, "ts": format_ts(sample["ts"])}
                if late:
                    out["replayed"] = True
                if bound is not None and sample["ts"] > bound:
                    out["ahead"] = True  # dated too far ahead: never the position
                return out

            if (rest := self.emit(topic, data)) is not None:
                pending.append(rest)
        return _both(*pending) if pending else None

    # ---- snapshots --------------------------------------------------------------
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
            docs = await self.events.latest(vehicle_id, RECENT_EVENTS)
            return {"events": [_jsonable(d) for d in docs]}
        return None


async def _both(*pending: Awaitable[None] | None) -> None:
    for rest in pending:
        if rest is not None:
            await rest


def _jsonable(value: Any) -> Any:
    """Datetimes in the contract's format, recursively; the rest as it is."""
    if isinstance(value, datetime):
        return format_ts(value)
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    return value
