"""A built server's life: its start-up work, its background loops and its shutdown.

:func:`start` does the start-up work (indexes, the state a former run left, the
admin) and then runs the background loops; when the store cannot be reached the
server serves all the same, says so on ``/readyz``, answers 503 and tries again
with a growing wait. :func:`shutdown` stops it all, each step on its own so that
one failing does not skip the others. What runs is a :class:`Runtime`, made by
:func:`server.container.build`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from datetime import timedelta

from server.api.live_hub import LiveHub
from server.metrics import Metrics
from server.services.registry import Services
from server.storage import Store

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
        for part in (
            services.auth,
            services.events,
            services.instances,
            services.control,
            services.zones,
        ):
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
    runtime.spawn("control requests", services.control_requests.sweep, 1.0)
    runtime.spawn("commands", services.commands.sweep, 0.2)
    runtime.spawn("safety", services.safety.tick, settings.rules_every_s)
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
        ("zone_versions", lambda: services.zones.repo.drop_versions_before(before)),
        ("obstacles_removed", lambda: services.obstacles.repo.drop_removed_before(before)),
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
        started = time.monotonic()
        try:
            await step()
        except Exception:
            log.exception("shutdown: %s failed; the rest goes on", name)
        if (took := time.monotonic() - started) > SLOW_STEP_S:
            log.warning("shutdown: %s took %.1f s", name, took)


#: A shutdown step longer than this is logged (what held the stop up, and how long).
SLOW_STEP_S = 1.0


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
