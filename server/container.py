"""The composition root: everything built once, in dependency order, and run.

:func:`build` opens the store and the bus, builds every service (each gets
what it needs in its constructor), the live hub, and registers the handlers
of the domain events the services emit: nothing is wired after
construction. What it returns is run by :mod:`server.running` (start-up, the
background loops, shutdown).
"""

from __future__ import annotations

import logging

from fleet_protocol import utcnow
from server.api.live_hub import LiveHub
from server.bus import make_bus
from server.domain.clock import Clock
from server.domain.events import (
    CommandMoved,
    CommandsReady,
    ControlChanged,
    EventRecorded,
    FailsafeChanged,
    InstanceFinished,
    LeaseEnded,
    LinkChanged,
    PresenceChanged,
    SamplesStored,
    StateWritten,
    TokensRevoked,
    UserChanged,
    ZonesChanged,
)
from server.metrics import Metrics
from server.running import Runtime
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
from server.services.registry import Services
from server.services.replicas import ReplicaSync
from server.services.safety import SafetyService
from server.services.telemetry import TelemetryService
from server.services.zones import ZoneService
from server.settings import Settings
from server.storage import Store, open_store
from server.storage.accounts import AccountsRepo
from server.storage.audit import AuditRepo
from server.storage.commands import CommandsRepo
from server.storage.control import ControlRepo
from server.storage.dead_letters import DeadLettersRepo
from server.storage.events import EventsRepo
from server.storage.instances import InstancesRepo
from server.storage.locks import LocksRepo
from server.storage.obstacles import ObstaclesRepo
from server.storage.safety import SafetyRepo
from server.storage.telemetry import TelemetryRepo
from server.storage.zones import ZonesRepo

log = logging.getLogger("fleet.server")


async def build(
    settings: Settings, metrics: Metrics, clock: Clock = utcnow, store: Store | None = None
) -> Runtime:
    """Everything of one server, built and wired; nothing started but the bus."""
    owns_store = store is None
    if store is None:
        store = open_store(settings)
    if store.kind == "embedded" and owns_store:
        log.warning(
            "embedded store (mongomock, in process), kept in %s; set FLEET_MONGO_URL for MongoDB",
            settings.snapshot_path,
        )
    bus = make_bus(settings)
    await bus.start()
    messages = MessageBus(on_failure=metrics.handler_error)
    dead_letters = DeadLetters(DeadLettersRepo(store), metrics.background_error, clock)

    def news_flows() -> bool:
        return not bus.remote or bus.healthy

    auth = AuthService(settings, AccountsRepo(store), messages, news_flows, clock)
    events = EventService(EventsRepo(store), messages, clock)
    audit = AuditLog(AuditRepo(store), dead_letters, clock)
    instances = InstanceService(
        settings, InstancesRepo(store), auth, events, messages, dead_letters, clock
    )
    control_repo = ControlRepo(store)  # the leases and the requests (indexes: control.load)
    control = ControlService(
        settings, control_repo, instances, auth, events, messages, dead_letters, clock
    )
    control_requests = ControlRequests(
        settings, control_repo, control, instances, auth, events, messages, dead_letters, clock
    )
    obstacles = ObstacleService(settings, ObstaclesRepo(store), events, clock)
    zones = ZoneService(settings, ZonesRepo(store), auth, events, messages, clock)
    commands = CommandService(
        settings,
        CommandsRepo(store),
        instances,
        control,
        events,
        messages,
        dead_letters,
        obstacles.zones,
        zones.current,
        clock,
        hops=metrics.hops,
    )
    safety = SafetyService(
        settings, SafetyRepo(store), instances, auth, zones, commands, events, messages, clock
    )
    forecast = CollisionForecast(settings, instances, events, LocksRepo(store), clock)
    telemetry = TelemetryService(settings, store, TelemetryRepo(store), dead_letters, clock)
    views = FleetViews(auth, instances, control, safety)
    link = VehicleLink(
        settings, instances, telemetry, control, commands, safety, messages, metrics.hops
    )
    topics = ServerTopics(bus, instances, commands, control, events, views)
    replicas = ReplicaSync(bus, instances, control, commands, safety, auth, messages, dead_letters)
    hub = LiveHub(settings, bus, instances, commands, control, topics, metrics.hops)
    services = Services(
        settings=settings,
        store=store,
        clock=clock,
        bus=bus,
        messages=messages,
        dead_letters=dead_letters,
        readiness=Readiness(),
        auth=auth,
        events=events,
        audit=audit,
        instances=instances,
        control=control,
        control_requests=control_requests,
        commands=commands,
        obstacles=obstacles,
        zones=zones,
        safety=safety,
        forecast=forecast,
        telemetry=telemetry,
        link=link,
        views=views,
        topics=topics,
        replicas=replicas,
    )
    # Who hears what: in the order given (a finish ends the lease, then the commands).
    messages.register(InstanceFinished, control.on_instance_finished)
    messages.register(InstanceFinished, control_requests.on_instance_finished)
    messages.register(InstanceFinished, commands.on_instance_finished)
    messages.register(InstanceFinished, lambda e: safety.forget(e.instance_id))
    messages.register(LeaseEnded, commands.on_lease_end)
    messages.register(UserChanged, control.on_user_changed)
    messages.register(UserChanged, control_requests.on_user_changed)
    messages.register(PresenceChanged, topics.on_presence)
    messages.register(LinkChanged, topics.on_link)
    messages.register(ControlChanged, topics.on_control)
    messages.register(EventRecorded, topics.on_event)
    messages.register(CommandMoved, topics.on_command_moved)
    messages.register(EventRecorded, audit.on_event)
    messages.register(CommandMoved, audit.on_command_moved)
    messages.register(SamplesStored, topics.on_samples)
    messages.register(SamplesStored, safety.on_samples)
    messages.register(FailsafeChanged, hub.on_failsafe_changed)
    messages.register(FailsafeChanged, commands.on_failsafe_changed)
    messages.register(FailsafeChanged, replicas.on_failsafe_changed)
    messages.register(FailsafeChanged, safety.on_failsafe_changed)
    messages.register(ZonesChanged, safety.on_zones_changed)
    messages.register(ZonesChanged, replicas.on_zones_changed)
    messages.register(SamplesStored, lambda e: metrics.samples.add(len(e.samples)))
    messages.register(CommandsReady, hub.on_commands_ready)
    messages.register(TokensRevoked, hub.on_tokens_revoked)
    messages.register(TokensRevoked, replicas.on_tokens_revoked)
    messages.register(StateWritten, replicas.on_state_written)
    await replicas.start()
    runtime = Runtime(services, hub, metrics, owns_store)
    _register_gauges(runtime)
    return runtime


def _register_gauges(runtime: Runtime) -> None:
    services = runtime.services

    def presence_counts() -> dict[str, float]:
        counts: dict[str, float] = {"online": 0, "stale": 0, "offline": 0}
        for state in services.instances.live():
            presence = services.instances.presence(state)
            counts[presence] = counts.get(presence, 0) + 1
        return counts

    runtime.metrics.live_gauge(
        "fleet_vehicles", "vehicles with a live instance, by presence", presence_counts, "presence"
    )

    def commands_by_status() -> dict[str, float]:
        return {k: float(v) for k, v in services.commands.counts_by_status().items()}

    runtime.metrics.live_gauge(
        "fleet_commands", "active commands by status", commands_by_status, "status"
    )
    runtime.metrics.live_gauge(
        "fleet_plans_running",
        "paths being planned (follow_path with plan), at most FLEET_PLAN_WORKERS",
        lambda: {"": float(services.commands.admission.planning.running)},
    )
    runtime.metrics.live_gauge(
        "fleet_ws_connections",
        "open WebSocket connections",
        lambda: {"": float(len(runtime.hub.connections))},
    )
