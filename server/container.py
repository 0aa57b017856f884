"""The composition root: everything built once, in dependency order, and run.

:func:`build` opens the store and the bus, builds every service (each gets
what it needs in its constructor), the live hub, and registers the handlers
of the domain events the services emit: nothing is wired after
construction. :func:`start` does the start-up work (indexes, the state a
former run left, the admin) and then runs the background loops; when the
store cannot be reached the server serves all the same, says so on
``/readyz``, answers 503 and tries again with a growing wait. :func:`shutdown`
stops it all, each step on its own so that one failing does not skip the
others.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from datetime import timedelta

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
from server.services.audit import AuditLog
from server.services.auth import AuthService
from server.services.commands import CommandService
from server.services.control import ControlService
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

#: First wait between tries to reach the store at start; it doubles up to the setting.
RETRY_MIN_S = 0.5


@dataclass
class Runtime:
    """One server: its services, its live hub, and what runs in the background."""

    services: Services
    hub: LiveHub
    metrics: Metrics
    #: False when the store was handed in (``create_app(store=...)``): its owner closes it.
    owns_store: bool
    #: A fresh admin token to print once (none when ``FLEET_ADMIN_TOKEN`` is set).
    admin_token: str | None = None
    tasks: list[asyncio.Task[None]] = field(default_factory=list)
    #: Set at shutdown: every loop ends at its next turn, even if a cancellation was lost.
    stopping: asyncio.Event = field(default_factory=asyncio.Event)

    def spawn(self, name: str, fn: Callable[[], Awaitable[None]], every_s: float) -> None:
        """Run ``fn`` every ``every_s`` seconds until shutdown. Each pass handles its own
        records; what still escapes it is logged and counted, and the loop goes on."""

        async def loop() -> None:
            while not self.stopping.is_set():
                try:
                    await fn()
                except asyncio.CancelledError:
                    raise
                except Exception:
                    log.exception("background %s failed; it goes on", name)
                    self.metrics.background_error(name)
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self.stopping.wait(), every_s)

        self.tasks.append(asyncio.create_task(loop(), name=name))


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
    control = ControlService(
        settings, ControlRepo(store), instances, auth, events, messages, dead_letters, clock
    )
    obstacles = ObstacleService(settings, ObstaclesRepo(store), clock)
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
    messages.register(InstanceFinished, commands.on_instance_finished)
    messages.register(InstanceFinished, lambda e: safety.forget(e.instance_id))
    messages.register(LeaseEnded, commands.on_lease_end)
    messages.register(UserChanged, control.on_user_changed)
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


# ---- start-up ----------------------------------------------------------------------------


async def start(runtime: Runtime) -> None:
    """Do the start-up work once now; if the store cannot be reached, keep trying in the
    background (the server serves meanwhile: 503 and ``/readyz`` false with the reason)."""
    if await _try_load(runtime):
        _start_background(runtime)
        return
    runtime.tasks.append(asyncio.create_task(_retry_load(runtime), name="startup"))


async def _try_load(runtime: Runtime) -> bool:
    services = runtime.services
    readiness = services.readiness
    try:
        if runtime.owns_store:
            await services.store.load()
        reason = await services.store.ping()
        if reason is not None:
            readiness.failed(reason)
            return False
        await services.dead_letters.repo.ensure_indexes()
        for part in (services.auth, services.events, services.instances, services.control):
            await part.load()
        await services.commands.load()
        await services.telemetry.load()
        await services.audit.load()
        await services.safety.tick()
        runtime.admin_token = await services.auth.bootstrap_admin()
    except Exception as exc:  # the store went away half-way: all of it again, later
        readiness.failed(f"start-up failed: {exc}")
        log.warning("start-up: %s; trying again", exc)
        return False
    readiness.done()
    if runtime.admin_token:
        # Shown once on the console for a new user; never logged.
        print(f"fleet-server: admin token (new at this start): {runtime.admin_token}", flush=True)
    return True


async def _retry_load(runtime: Runtime) -> None:
    services = runtime.services
    wait = RETRY_MIN_S
    log.error(
        "the store cannot be reached at start-up (%s); trying again", services.readiness.reason
    )
    while not runtime.stopping.is_set():
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(runtime.stopping.wait(), wait)
        if runtime.stopping.is_set():
            return
        if await _try_load(runtime):
            log.info("start-up done after %d tries", services.readiness.attempts + 1)
            _start_background(runtime)
            return
        wait = min(wait * 2, services.settings.store_retry_max_s)


def _start_background(runtime: Runtime) -> None:
    services = runtime.services
    settings = services.settings
    runtime.spawn("presence", services.instances.sweep, 0.25)
    runtime.spawn("leases", services.control.sweep, 0.2)
    runtime.spawn("commands", services.commands.sweep, 0.2)
    runtime.spawn("safety", services.safety.tick, 1.0)
    runtime.spawn("forecast", services.forecast.tick, settings.forecast_every_s)
    runtime.spawn("telemetry", services.telemetry.writer_step, services.telemetry.writer_tick_s())
    if services.store.kind == "embedded" and runtime.owns_store:
        runtime.spawn("journal", lambda: _flush(services.store), settings.snapshot_interval_s)
    runtime.spawn("retention", lambda: _retention(services), 60.0)
    runtime.spawn("demand", runtime.hub.demand.step, 0.25)  # across replicas (live_demand)


async def _flush(store: Store) -> None:
    await store.flush()


async def _retention(services: Services) -> None:
    """Drop what is older than ``FLEET_RETENTION_S``, one collection at a time."""
    now = services.clock()
    before = now - timedelta(seconds=services.settings.retention_s)
    steps: list[tuple[str, Callable[[], Awaitable[int]]]] = [
        ("events", lambda: services.events.drop_before(before)),
        ("commands", lambda: services.commands.drop_finished_before(before)),
        ("telemetry", lambda: services.telemetry.drop_before(before)),
        ("instances", lambda: services.instances.drop_finished_before(before)),
        ("dead_letters", lambda: services.dead_letters.drop_before(before)),
        ("tokens", lambda: services.auth.repo.drop_expired_tokens(now)),
        ("login_attempts", lambda: services.auth.drop_old_login_attempts(now)),
    ]
    for name, step in steps:
        try:
            await step()
        except Exception as exc:
            services.dead_letters.failed("retention", exc)
            log.warning("retention of %s failed (%r); the others go on", name, exc)


# ---- shutdown -----------------------------------------------------------------------------


async def shutdown(runtime: Runtime) -> None:
    services = runtime.services
    steps: list[tuple[str, Callable[[], Awaitable[None]]]] = [
        ("sockets", runtime.hub.stop),
        ("background", lambda: _stop_tasks(runtime)),
        ("replicas", services.replicas.stop),
        ("bus", services.bus.close),
    ]
    if services.readiness.loaded:
        steps += [
            ("contact", lambda: services.instances.write_back(everything=True)),
            ("telemetry", services.telemetry.flush_all),
        ]
    steps.append(("handlers", services.messages.drain))
    if runtime.owns_store:
        steps.append(("store", services.store.close))
    for name, step in steps:
        try:
            await step()
        except Exception:
            log.exception("shutdown: %s failed; the rest goes on", name)


#: How long shutdown waits for a background loop to end.
STOP_WAIT_S = 5.0


async def _stop_tasks(runtime: Runtime) -> None:
    """Stop every loop: cancelled, and told by ``stopping`` in case a cancellation is lost
    inside a driver call (Python 3.11's ``wait_for`` can swallow one)."""
    runtime.stopping.set()
    for task in runtime.tasks:
        task.cancel()
    if runtime.tasks:
        _, late = await asyncio.wait(runtime.tasks, timeout=STOP_WAIT_S)
        for task in late:
            log.error("shutdown: background %s did not stop in time", task.get_name())
    runtime.tasks.clear()
