"""The durable outbox: numbering, draining, durability, bound, seen ids."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from vehicle_client.outbox import Outbox, OutboxTaken


def make_sample(i: int = 0) -> dict:
    return {"ts": f"2026-11-22T10:00:{i % 60:02d}.000Z", "lat": 43.94, "lon": 15.44 + i * 1e-6}


def fill(outbox: Outbox, n: int) -> list[int]:
    return [outbox.append(make_sample(i)) for i in range(n)]


def test_samples_get_rising_seqs_above_the_servers_last_seq(tmp_path: Path) -> None:
    outbox = Outbox(tmp_path / "o.db")
    outbox.match_server(last_seq=41)
    assert fill(outbox, 3) == [42, 43, 44]
    assert [s["seq"] for s in outbox.batch()] == [42, 43, 44]


def test_samples_taken_before_the_server_answered_are_renumbered_once(tmp_path: Path) -> None:
    outbox = Outbox(tmp_path / "o.db")
    fill(outbox, 3)  # 1, 2, 3 while offline on a fresh install
    outbox.match_server(last_seq=100)
    assert [s["seq"] for s in outbox.batch()] == [101, 102, 103]
    assert outbox.append(make_sample()) == 104
    outbox.match_server(last_seq=2)  # later answers never move numbering back
    assert outbox.append(make_sample()) == 105


def test_batches_drain_oldest_first_after_a_cursor(tmp_path: Path) -> None:
    outbox = Outbox(tmp_path / "o.db")
    fill(outbox, 10)
    assert [s["seq"] for s in outbox.batch(limit=4)] == [1, 2, 3, 4]
    assert [s["seq"] for s in outbox.batch(after_seq=4, limit=4)] == [5, 6, 7, 8]
    assert outbox.batch(after_seq=10) == []


def test_only_durable_samples_are_deleted(tmp_path: Path) -> None:
    outbox = Outbox(tmp_path / "o.db")
    fill(outbox, 10)
    assert outbox.confirm_durable(6) == 6
    assert outbox.pending == 4
    assert [s["seq"] for s in outbox.batch()] == [7, 8, 9, 10]


def test_contents_survive_a_reopen(tmp_path: Path) -> None:
    path = tmp_path / "o.db"
    first = Outbox(path)
    first.match_server(0)
    fill(first, 5)
    first.confirm_durable(2)
    first.seen["c1"] = "executing"
    first.close()
    again = Outbox(path)
    assert [s["seq"] for s in again.batch()] == [3, 4, 5]
    assert again.pending == 3
    assert again.append(make_sample()) == 6
    assert again.seen["c1"] == "executing"
    assert again.seen.unfinished() == ["c1"]


def test_past_the_bound_the_oldest_samples_are_dropped_and_counted(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    outbox = Outbox(tmp_path / "o.db", max_samples=5)
    fill(outbox, 8)
    assert outbox.pending == 5
    assert [s["seq"] for s in outbox.batch()] == [4, 5, 6, 7, 8]
    assert outbox.dropped == 3
    assert "outbox full" in caplog.text


def test_seen_commands_are_bounded_newest_kept(tmp_path: Path) -> None:
    outbox = Outbox(tmp_path / "o.db", max_seen=3)
    for i in range(5):
        outbox.seen[f"c{i}"] = "done"
    assert sorted(outbox.seen) == ["c2", "c3", "c4"]
    assert outbox.seen.get("c0") is None


def test_default_bound_holds_a_day_at_one_hertz(tmp_path: Path) -> None:
    assert Outbox(tmp_path / "o.db").max_samples >= 86_400


def test_bad_bounds_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError):
        Outbox(tmp_path / "o.db", max_samples=0)


def test_the_outbox_is_its_owners_alone_whatever_the_umask(tmp_path: Path) -> None:
    """It holds the vehicle's readings and the commands it has seen: 0600 in a 0700 folder
    it makes, and a file an older version left readable is made the owner's alone."""
    former = os.umask(0o022)
    try:
        made = Outbox(tmp_path / "new" / "o.db")
        made.append({"ts": "2026-11-22T10:00:00.000Z", "lat": 1.0, "lon": 2.0})
        made.close()
        old = tmp_path / "old.db"
        old.touch(mode=0o644)
        Outbox(old).close()
    finally:
        os.umask(former)
    assert stat.S_IMODE((tmp_path / "new").stat().st_mode) == 0o700
    for path in (tmp_path / "new" / "o.db", old):
        assert stat.S_IMODE(path.stat().st_mode) == 0o600, path
    for journal in (tmp_path / "new").glob("o.db-*"):
        assert stat.S_IMODE(journal.stat().st_mode) & 0o077 == 0, journal


def test_an_outbox_is_one_vehicles(tmp_path: Path) -> None:
    """The first vehicle to open it owns it, one an older version wrote (no owner) too;
    another vehicle is refused, and nothing of the outbox changes for it."""
    path = tmp_path / "o.db"
    legacy = Outbox(path)  # an older version's: no owner
    fill(legacy, 3)
    legacy.close()
    owned = Outbox(path, vehicle_id="usv-1")
    assert owned.pending == 3
    owned.close()
    with pytest.raises(OutboxTaken) as refused:
        Outbox(path, vehicle_id="usv-2")
    assert refused.value.owner == "usv-1" and "usv-2 its own" in str(refused.value)
    again = Outbox(path, vehicle_id="usv-1")
    assert [s["seq"] for s in again.batch()] == [1, 2, 3]
    again.close()
