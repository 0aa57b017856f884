"""The agent daemon over HTTP, against an in-memory ``/upper/*`` (fake_upper).

Every wait is a deadline loop on a condition; nothing asserts on timing.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable
from pathlib import Path

import pytest

from tests.agent.fake_upper import TOKEN, FakeUpper
from vehicle_client.adapters.sim import SimAdapter
from vehicle_client.agent import AgentConfig, VehicleAgent
from vehicle_client.backoff import Backoff
from vehicle_client.errors import FatalError
from vehicle_client.outbox import Outbox
from vehicle_client.sim import Current
from vehicle_client.transport.http import HttpTransport

START = (43.94, 15.44)
DEADLINE_S = 20.0


async def wait_for(condition: Callable[[], bool], what: str, within_s: float = DEADLINE_S) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + within_s
    while not condition():
        if loop.time() > deadline:
            raise AssertionError(f"gave up waiting: {what}")
        await asyncio.sleep(0.02)


def make_agent(
    fake: FakeUpper,
    outbox_path: Path,
    *,
    token: str = TOKEN,
    rate_hz: float = 20.0,
    time_scale: float = 40.0,
    current: Current | None = None,
) -> VehicleAgent:
    transport = HttpTransport("http://fleet.test", token, transport=fake.transport())
    adapter = SimAdapter(*START, time_scale=time_scale, current=current)
    config = AgentConfig(vehicle_id=fake.vehicle_id, rate_hz=rate_hz, batch_size=25)
    return VehicleAgent(config, adapter, transport, Outbox(outbox_path), backoff=Backoff(0.02, 0.1))


@contextlib.asynccontextmanager
async def running(agent: VehicleAgent) -> AsyncIterator[asyncio.Task]:
    task = asyncio.create_task(agent.run())
    try:
        yield task
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        agent.outbox.close()


def point(agent: VehicleAgent, east: float, north: float) -> dict[str, float]:
    lat, lon = agent.adapter.sim.frame.to_latlon(east, north)  # type: ignore[attr-defined]
    return {"lat": lat, "lon": lon}


async def test_a_refused_token_stops_the_agent_with_a_clear_message(tmp_path: Path) -> None:
    agent = make_agent(FakeUpper(), tmp_path / "o.db", token="wrong")
    with pytest.raises(FatalError, match="refused the token"):
        await asyncio.wait_for(agent.run(), DEADLINE_S)
    agent.outbox.close()


def test_a_bad_server_url_is_fatal() -> None:
    with pytest.raises(FatalError, match="http"):
        HttpTransport("fleet.example:8000", TOKEN)


async def test_samples_are_numbered_above_last_seq_and_deleted_once_durable(
    tmp_path: Path,
) -> None:
    fake = FakeUpper(last_seq=500, durable_lag=5)
    agent = make_agent(fake, tmp_path / "o.db")
    async with running(agent):
        await wait_for(lambda: len(fake.stored) >= 30, "30 samples stored")
        await wait_for(lambda: agent.outbox.oldest_seq() is not None, "a sample not yet durable")
        durable = fake.last_seq - fake.durable_lag
        assert agent.outbox.oldest_seq() > durable - 2  # nothing durable lingers long
        assert fake.stored_seqs()[:3] == [501, 502, 503]
        seqs = fake.stored_seqs()
        assert seqs == list(range(501, 501 + len(seqs)))


async def test_an_outage_loses_no_sample_and_stores_none_twice(tmp_path: Path) -> None:
    fake = FakeUpper(durable_lag=3)
    agent = make_agent(fake, tmp_path / "o.db")
    async with running(agent):
        await wait_for(lambda: len(fake.stored) >= 10, "first samples")
        fake.down = True
        await wait_for(lambda: agent.outbox.pending >= 60, "a backlog while down")
        fake.down = False
        target = agent.outbox.next_seq - 1
        await wait_for(lambda: fake.last_seq >= target, "the backlog delivered")
    seqs = fake.stored_seqs()
    assert seqs == list(range(1, len(seqs) + 1))
    assert agent.stats.sessions >= 2


async def test_go_to_is_acked_accepted_executing_done(tmp_path: Path) -> None:
    fake = FakeUpper()
    agent = make_agent(fake, tmp_path / "o.db", current=Current(0.05, 0.0))
    async with running(agent):
        cid = fake.add_command("go_to", point(agent, 15.0, 10.0))
        await wait_for(lambda: "done" in fake.statuses(cid), "go_to done")
    statuses = fake.statuses(cid)
    assert statuses[:2] == ["accepted", "executing"]
    assert statuses.count("done") == 1
    assert "remote" in fake.modes


async def test_an_expired_command_is_rejected_and_not_executed(tmp_path: Path) -> None:
    fake = FakeUpper()
    agent = make_agent(fake, tmp_path / "o.db")
    async with running(agent):
        cid = fake.add_command("go_to", point(agent, 50.0, 0.0), ttl_s=-1)
        await wait_for(lambda: fake.statuses(cid) != [], "an answer to the command")
        assert fake.statuses(cid) == ["rejected"]
        assert agent.adapter.sim.task is None  # type: ignore[attr-defined]


async def test_an_aborted_command_is_halted_and_never_reported_done(tmp_path: Path) -> None:
    fake = FakeUpper()
    agent = make_agent(fake, tmp_path / "o.db", time_scale=1.0)
    async with running(agent):
        cid = fake.add_command("go_to", point(agent, 500.0, 0.0))
        fake.abort.add(cid)
        await wait_for(lambda: agent.helm.pilot.seen.get(cid) == "aborted", "the abort taken")
        assert agent.adapter.sim.task is None  # type: ignore[attr-defined]
        assert agent.helm.pilot.control_mode == "idle"
    assert "done" not in fake.statuses(cid)


async def test_link_loss_engages_the_failsafe_and_says_so_when_back(tmp_path: Path) -> None:
    fake = FakeUpper(failsafe_after_s=0.5)
    agent = make_agent(fake, tmp_path / "o.db", time_scale=1.0)
    async with running(agent):
        cid = fake.add_command("go_to", point(agent, 500.0, 0.0))
        await wait_for(lambda: "executing" in fake.statuses(cid), "go_to under way")
        fake.down = True
        await wait_for(lambda: agent.helm.pilot.control_mode == "failsafe", "failsafe engaged")
        assert agent.adapter.sim.task.kind == "keep_station"  # type: ignore[attr-defined]
        fake.down = False
        await wait_for(lambda: "failed" in fake.statuses(cid), "the interrupted go_to reported")
        await wait_for(lambda: "failsafe" in fake.params, "failsafe told in params")
        await wait_for(lambda: "failsafe" in fake.modes, "failsafe control mode reported")
        assert fake.params["failsafe"]["action"] == "keep_station"
        # The next command it accepts ends the failsafe: its parameter goes.
        nxt = fake.add_command("go_to", point(agent, 0.0, 500.0))
        await wait_for(lambda: "executing" in fake.statuses(nxt), "the next command under way")
        await wait_for(lambda: "failsafe" not in fake.params, "the failsafe parameter cleared")
        assert agent.helm.pilot.control_mode == "remote"


async def test_a_restarted_agent_resumes_its_outbox_and_ignores_seen_commands(
    tmp_path: Path,
) -> None:
    fake = FakeUpper(durable_lag=1000)  # nothing durable: everything stays in the outbox
    first = make_agent(fake, tmp_path / "o.db")
    async with running(first):
        cid = fake.add_command("go_to", point(first, 3.0, 0.0))
        await wait_for(lambda: "done" in fake.statuses(cid), "go_to done")
        await wait_for(lambda: len(fake.stored) >= 20, "samples sent")
    fake.stored.clear()
    fake.last_seq = 0  # as if the server lost what was not durable
    fake._acked.discard(cid)  # and hands the command out again
    second = make_agent(fake, tmp_path / "o.db")
    async with running(second):
        await wait_for(lambda: fake.statuses(cid).count("done") >= 2, "the repeat answered")
        await wait_for(lambda: len(fake.stored) >= 25, "the old outbox re-sent")
    seqs = fake.stored_seqs()
    assert seqs[0] == 1 and seqs == list(range(1, len(seqs) + 1))
    assert fake.statuses(cid).count("accepted") == 1  # executed once only
