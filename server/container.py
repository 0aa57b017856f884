"""The services, built once in the app's lifespan and handed to routes by dependency."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from typing import Any

from fleet_protocol import utcnow
from server.bus import Bus, make_bus
from server.metrics import Metrics
from server.services.auth import AuthService
from server.services.commands import CommandService
from server.services.control import ControlService
from server.services.events import EventService
from server.services.fleet import FleetViews
from server.services.instances import InstanceService
from server.services.link import VehicleLink
from server.services.live import LiveHub
from server.services.obstacles import ObstacleService
from server.services.replicas import ReplicaSync
from server.services.telemetry import TelemetryService
from server.settings import Settings
from server.storage import Store, open_store
from server.storage.accounts import AccountsRepo
from server.storage.commands import CommandsRepo
from server.storage.control import ControlRepo
from server.storage.events import EventsRepo
from server.storage.instances import InstancesRepo
from server.storage.obstacles import ObstaclesRepo

log = logging.getLogger("fleet.server")
Clock = Callable[[], datetime]


@dataclass
class Services:
    settings: Settings
    store: Store
    clock: Clock
    metrics: Metrics
    auth: AuthService
    events: EventService
    instances: InstanceService
    control: ControlService
    commands: CommandService
    telemetry: TelemetryService
    link: VehicleLink
    views: FleetViews
    bus: Bus
    live: LiveHub
    obstacles: ObstacleService
    extra: dict[str, Any] = field(default_factory=dict)
    tasks: list[asyncio.Task[None]] = field(default_factory=list)
    admin_token: str | None = None
    #: Several replicas (``FLEET_REDIS_URL``): what keeps this one's copies in step.
    replicas: ReplicaSync | None = None
    #: False when the store was handed in (``create_app(store=...)``): its owner closes it.
    owns_store: bool = True

    def spawn(self, name: str, fn: Callable[[], Awaitable[None]], every_s: float) -> None:
        """Run ``fn`` every ``every_s`` seconds until shutdown; failures are logged, not fatal."""

        async def loop() -> None:
            while True:
                try:
                    await fn()
                except asyncio.CancelledError:
                    raise
                except Exception:
                    log.exception("background task %s failed; it goes on", name)
                await asyncio.sleep(every_s)

        self.tasks.append(asyncio.create_task(loop(), name=name))

    async def stop_tasks(self) -> None:
        for task in self.tasks:
            task.cancel()
        for task in self.tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self.tasks.clear()


async def build(
    settings: Settings, metrics: Metrics, clock: Clock = utcnow, store: Store | None = None
) -> Services:
    """The services; on ``store`` when given (the caller opened it and closes it)."""
    owns_store = store is None
    store = store or open_store(settings)
    if store.embedded and owns_store:
        log.warning(
            "embedded store (mongomock, in process), kept in %s; set FLEET_MONGO_URL for MongoDB",
            settings.snapshot_path,
        )
        await store.load()
    accounts = AccountsRepo(store)
    events_repo = EventsRepo(store)
    instances_repo = InstancesRepo(store)
    if await store.ping():
        for repo in (accounts, events_repo, instances_repo):
            await repo.ensure_indexes()
    auth = AuthService(settings, accounts)
    events = EventService(events_repo, clock)
    instances = InstanceService(settings, instances_repo, auth, events, clock)
    control = ControlService(settings, ControlRepo(store), instances, auth, events, clock)
    commands = CommandService(settings, CommandsRepo(store), instances, control, events, clock)
    obstacles = ObstacleService(settings, ObstaclesRepo(store), clock)
    commands.admission.zones = obstacles.zones  # planned paths keep clear of them
    telemetry = TelemetryService(settings, store, clock)
    views = FleetViews(auth, instances, control)
    link = VehicleLink(settings, instances, telemetry, control)
    bus = make_bus(settings)
    await bus.start()
    live = LiveHub(settings, bus, instances, commands, control, events, views)
    link.sample_listeners.append(live.topics.telemetry)
    auth.on_revoke(live.revoked)
    services = Services(
        settings,
        store,
        clock,
        metrics,
        auth,
        events,
        instances,
        control,
        commands,
        telemetry,
        link=link,
        views=views,
        bus=bus,
        live=live,
        obstacles=obstacles,
        owns_store=owns_store,
    )
    if settings.shared_state:
        services.replicas = ReplicaSync(bus, instances, control, commands)
        await services.replicas.start()
    if await store.ping():
        await instances.load()
        await control.load()
        await commands.load()
        await telemetry.load()
        services.admin_token = await auth.bootstrap_admin()
    else:
        log.error("the store cannot be reached at start-up; /readyz says so until it can")
    _register_gauges(services)
    return services


def _register_gauges(services: Services) -> None:
    def presence_counts() -> dict[str, float]:
        counts: dict[str, float] = {"online": 0, "stale": 0, "offline": 0}
        for state in services.instances.live():
            presence = services.instances.presence(state)
            counts[presence] = counts.get(presence, 0) + 1
        return counts

    services.metrics.live_gauge(
        "fleet_vehicles", "vehicles with a live instance, by presence", presence_counts, "presence"
    )

    def commands_by_status() -> dict[str, float]:
        return {k: float(v) for k, v in services.commands.counts_by_status().items()}

    services.metrics.live_gauge(
        "fleet_commands", "active commands by status", commands_by_status, "status"
    )
    services.metrics.live_gauge(
        "fleet_ws_connections",
        "open WebSocket connections",
        lambda: {"": float(len(services.live.connections))},
    )


def start_background(services: Services) -> None:
    settings = services.settings
    services.spawn("presence", services.instances.sweep, 0.25)
    services.spawn("leases", services.control.sweep, 0.2)
    services.spawn("commands", services.commands.sweep, 0.2)
    services.tasks.append(asyncio.create_task(services.telemetry.run_writer(), name="telemetry"))
    if services.store.embedded and services.owns_store:
        services.spawn("journal", _flush(services), settings.snapshot_interval_s)
    services.spawn("retention", _retention(services), 60.0)


def _flush(services: Services) -> Callable[[], Awaitable[None]]:
    async def flush() -> None:
        await services.store.flush()

    return flush


def _retention(services: Services) -> Callable[[], Awaitable[None]]:
    async def drop_old() -> None:
        before = services.clock() - timedelta(seconds=services.settings.retention_s)
        await services.events.drop_before(before)
        await services.commands.drop_finished_before(before)
        await services.telemetry.drop_before(before)
        await services.instances.drop_finished_before(before)
        await services.auth.repo.drop_expired_tokens(services.clock())

    return drop_old


async def shutdown(services: Services) -> None:
    with contextlib.suppress(Exception):
        await services.live.stop()
    await services.stop_tasks()
    if services.replicas is not None:
        with contextlib.suppress(Exception):
            await services.replicas.stop()
    with contextlib.suppress(Exception):
        await services.bus.close()
    with contextlib.suppress(Exception):
        await services.instances.sweep(everything=True)
    with contextlib.suppress(Exception):
        await services.telemetry.flush_all()
    if services.owns_store:
        await services.store.close()
