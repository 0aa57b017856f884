"""A reading the server would refuse is left out on the vehicle: logged with its seq (never
its payload), counted, never queued or re-sent; the good readings around it go through."""

from __future__ import annotations

import json
import logging
import math
import sqlite3
from pathlib import Path
from typing import Any

import pytest

from tests.agent.fake_upper import FakeUpper
from tests.agent.test_daemon import make_agent, running, wait_for
from vehicle_client.adapters.sim import SimAdapter
from vehicle_client.outbox import Outbox

TS = "2026-11-22T10:00:00.000Z"
BAD_DATA = [{"big": 2**64}, {"nan": math.nan}, {"text": "bad \ud800"}, {"$set": 1}]


def reading(**data: Any) -> dict[str, Any]:
    return {"ts": TS, "lat": 43.94, "lon": 15.44, "data": data}


def test_the_outbox_refuses_a_bad_reading_and_keeps_the_good_ones_around_it(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    outbox = Outbox(tmp_path / "o.db")
    caplog.set_level(logging.ERROR, logger="vehicle_client.outbox")
    seqs = [outbox.append(reading(n=1))]
    seqs += [outbox.append(reading(**data)) for data in BAD_DATA]
    seqs.append(outbox.append(reading(n=2)))
    assert seqs == [1, None, None, None, None, 6]  # a refused reading's seq stays unused
    assert [s["seq"] for s in outbox.batch()] == [1, 6]
    assert outbox.refused == 4 and outbox.pending == 2
    logged = [r.getMessage() for r in caplog.records]
    assert len(logged) == 4
    assert "sample seq 2 refused" in logged[0] and "data.big" in logged[0]
    assert "sample seq 5 refused" in logged[3] and "data.$set" in logged[3]
    assert not any(str(2**64) in m or "\ud800" in m or "bad " in m for m in logged)
    outbox.close()
    assert Outbox(tmp_path / "o.db").refused == 4  # kept in the file


class FaultySensor(SimAdapter):
    """The simulator, with a bad value in every third reading."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.readings = 0

    def telemetry(self) -> dict[str, Any]:
        fields = super().telemetry()
        self.readings += 1
        if self.readings % 3 == 0:
            bad = BAD_DATA[(self.readings // 3) % len(BAD_DATA)]
            return {**fields, "data": {"reading": self.readings, **bad}}
        return {**fields, "data": {"reading": self.readings}}


async def test_bad_readings_are_dropped_and_the_good_ones_sent(tmp_path: Path) -> None:
    fake = FakeUpper()
    agent = make_agent(fake, tmp_path / "o.db")
    agent.adapter = FaultySensor(43.94, 15.44, time_scale=40.0)
    async with running(agent):
        await wait_for(lambda: len(fake.stored) >= 12, "twelve good readings on the server")
        assert agent.outbox.refused >= 4
    sent = [s["data"] for s in fake.stored]
    assert all(set(d) == {"reading"} and d["reading"] % 3 for d in sent), sent
    seqs = fake.stored_seqs()
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    assert max(seqs) > len(seqs)  # the refused readings' seqs were skipped, not reused


async def test_a_bad_row_stored_by_an_older_agent_is_taken_out_not_resent_forever(
    tmp_path: Path,
) -> None:
    path = tmp_path / "o.db"
    Outbox(path).close()
    db = sqlite3.connect(path)  # rows as an agent without the check wrote them
    rows = [
        {"seq": 1, "ts": TS, "lat": 43.94, "lon": 15.44},
        {"seq": 2, "ts": TS, "lat": 43.94, "lon": 15.44, "data": {"x": math.nan}},
        {"seq": 3, "ts": "0001-01-01T00:00:00Z", "lat": 43.94, "lon": 15.44},
        {"seq": 4, "ts": TS, "lat": 43.94, "lon": 15.44},
    ]
    db.executemany(
        "INSERT INTO samples (seq, body) VALUES (?, ?)", [(r["seq"], json.dumps(r)) for r in rows]
    )
    db.execute("INSERT INTO meta (key, value) VALUES ('next_seq', '5'), ('matched', '1')")
    db.commit()
    db.close()
    fake = FakeUpper()
    agent = make_agent(fake, path, rate_hz=1.0)
    async with running(agent):
        await wait_for(lambda: {1, 4} <= set(fake.stored_seqs()), "the good old rows sent")
        await wait_for(lambda: agent.outbox.refused == 2, "the bad rows taken out")
        await wait_for(lambda: agent.outbox.pending == 0, "the outbox drained")
    assert 2 not in fake.stored_seqs() and 3 not in fake.stored_seqs()


async def test_parameters_the_server_refuses_are_dropped_and_the_samples_go_on(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A server with a rule this agent lacks (the bound on a vehicle's parameters once
    merged) refuses them, 422 naming ``params``: the agent logs it, drops them, and sends
    its samples without them, rather than the same refused call for ever."""
    fake = FakeUpper(failsafe_after_s=0.5, refuse_params=True)
    agent = make_agent(fake, tmp_path / "o.db", time_scale=1.0)
    caplog.set_level(logging.ERROR, logger="vehicle_client.agent")
    async with running(agent):
        await wait_for(lambda: len(fake.stored) >= 3, "samples sent")
        fake.down = True  # the link lost: the failsafe engages and goes into params
        await wait_for(lambda: agent.helm.pilot.control_mode == "failsafe", "failsafe engaged")
        fake.down = False
        await wait_for(lambda: fake.refused_params >= 1, "the params refused")
        sent = len(fake.stored)
        await wait_for(lambda: len(fake.stored) >= sent + 5, "samples after the refusal")
    assert fake.refused_params == 1 and "failsafe" not in fake.params
    assert any("parameters not sent" in r.getMessage() for r in caplog.records)
