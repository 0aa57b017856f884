"""The services of one server, built once by the composition root (``server/container.py``).

Routes and sockets reach them through this one object; nothing here builds
or wires anything.
"""

from __future__ import annotations

from dataclasses import dataclass

from server.bus import Bus
from server.domain.clock import Clock
from server.services.audit import AuditLog
from server.services.auth import AuthService
from server.services.commands import CommandService
from server.services.control import ControlService
from server.services.control_requests import ControlRequests
from server.services.dead_letters import DeadLetters
from server.services.events import EventService
from server.services.fleet import FleetViews
from server.services.forecast import CollisionForecast
from server.services.instances import InstanceService
from server.services.link import VehicleLink
from server.services.live_topics import ServerTopics
from server.services.messagebus import MessageBus
from server.services.obstacles import ObstacleService
from server.services.readiness import Readiness
from server.services.replicas import ReplicaSync
from server.services.safety import SafetyService
from server.services.telemetry import TelemetryService
from server.services.zones import ZoneService
from server.settings import Settings
from server.storage import Store


@dataclass
class Services:
    settings: Settings
    store: Store
    clock: Clock
    bus: Bus
    messages: MessageBus
    dead_letters: DeadLetters
    readiness: Readiness
    auth: AuthService
    events: EventService
    audit: AuditLog
    instances: InstanceService
    control: ControlService
    control_requests: ControlRequests
    commands: CommandService
    obstacles: ObstacleService
    zones: ZoneService
    safety: SafetyService
    forecast: CollisionForecast
    telemetry: TelemetryService
    link: VehicleLink
    views: FleetViews
    topics: ServerTopics
    replicas: ReplicaSync
