"""The embedded store's files: what a crash or a failed compaction leaves is read right."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from server.settings import Settings
from server.storage import Store, open_store
from server.storage import journal as journal_module


def settings_at(path: Path) -> Settings:
    return Settings(_env_file=None, snapshot_path=path / "store.snapshot")  # type: ignore[call-arg]


async def opened(path: Path) -> Store:
    store = open_store(settings_at(path))
    await store.load()
    return store


async def ids(store: Store) -> list[Any]:
    return sorted(d["_id"] for d in await store["things"].find({}))


async def test_flushed_writes_survive_a_crash_and_unflushed_ones_do_not(tmp_path: Path) -> None:
    store = await opened(tmp_path)
    await store["things"].insert({"_id": 1, "n": 1})
    await store["things"].update({"_id": 1}, set={"n": 2})
    await store.flush()
    await store["things"].insert({"_id": 2, "n": 1})  # never flushed
    again = await opened(tmp_path)  # the first one "crashed": no close
    assert await again["things"].find({}) == [{"_id": 1, "n": 2}]
    await again.close()


async def test_a_journal_older_than_the_base_is_not_replayed(tmp_path: Path) -> None:
    """A crash between the compaction's two renames leaves the former journal beside the
    new base, which holds its writes already: it is skipped, not applied again."""
    import bson

    store = await opened(tmp_path)
    await store["things"].insert({"_id": 1})
    await store.flush()
    await store.close()  # compaction: base of generation 1 holding {1}, journal emptied
    journal = tmp_path / "store.snapshot.journal"
    insert_99 = journal_module.Journal.encode("insert", "things", docs=[{"_id": 99}])
    journal.write_bytes(bson.encode({"gen": 0}) + insert_99)  # the former generation's
    again = await opened(tmp_path)
    assert await ids(again) == [1]
    await again.close()
    with (tmp_path / "store.snapshot").open("rb") as fh:
        generation = next(bson.decode_file_iter(fh))["gen"]
    journal.write_bytes(bson.encode({"gen": generation}) + insert_99)  # the base's own
    third = await opened(tmp_path)
    assert await ids(third) == [1, 99]
    await third.close()


async def test_a_failed_compaction_keeps_the_former_files_and_the_pending_writes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    store = await opened(tmp_path)
    await store["things"].insert({"_id": 1})
    await store.flush()
    await store["things"].insert({"_id": 2})  # pending, not flushed
    base = tmp_path / "store.snapshot"
    before = base.read_bytes() if base.exists() else None

    def disk_full(new: Any) -> None:  # the new base cannot be made durable
        new.drop()  # given up, as finish gives it up on a failure
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(journal_module._NewFile, "finish", disk_full)
    with pytest.raises(OSError):
        await store.close()
    assert (base.read_bytes() if base.exists() else None) == before
    assert not (tmp_path / "store.snapshot.tmp").exists()
    monkeypatch.undo()
    await store.flush()  # the write compaction did not fold in reaches the journal
    again = await opened(tmp_path)
    assert await ids(again) == [1, 2]
    await again.close()


async def test_a_stored_entry_that_cannot_be_replayed_is_set_aside(tmp_path: Path) -> None:
    store = await opened(tmp_path)
    await store["things"].insert({"_id": 1})
    await store["things"].insert({"_id": 2})
    await store.flush()
    journal = tmp_path / "store.snapshot.journal"
    # An entry this version cannot apply (an operator it does not know), between good ones.
    bad = journal_module.Journal.encode("update", "things", flt={"_id": 1}, update={"$inc": {}})
    with journal.open("ab") as fh:
        fh.write(bad)
        fh.write(journal_module.Journal.encode("insert", "things", docs=[{"_id": 3}]))
    again = await opened(tmp_path)
    assert await ids(again) == [1, 2, 3]
    assert (tmp_path / "store.snapshot.rejected").stat().st_size > 0
    await again.close()


async def test_a_journal_that_outgrows_the_base_is_folded_in_while_running(
    tmp_path: Path,
) -> None:
    """Inserts and deletes (a retention loop's work) grow the journal, not the data: once
    it is past the floor and twice the base, a flush folds it in; a crash after that
    restores exactly what was flushed."""
    store = await opened(tmp_path)
    store.compact_floor_bytes = 64 * 1024  # type: ignore[attr-defined]
    journal = tmp_path / "store.snapshot.journal"
    largest = 0
    for n in range(400):
        await store["things"].insert({"_id": n, "blob": "x" * 1000})
        if n >= 10:
            await store["things"].delete({"_id": n - 10})  # ten kept at any time
        await store.flush()
        largest = max(largest, journal.stat().st_size)
    # 400 KB written and deleted again: the files stay near the floor, not the traffic
    assert largest < 3 * 64 * 1024, largest
    assert (tmp_path / "store.snapshot").stat().st_size < 64 * 1024
    again = await opened(tmp_path)  # the first one "crashed": no close
    assert await ids(again) == list(range(390, 400))
    await again.close()


async def test_writes_made_while_a_compaction_encodes_are_all_kept(tmp_path: Path) -> None:
    """Compaction lets the event loop go between chunks of documents: the writes made
    meanwhile (inserts, updates, deletes) are neither lost nor folded in twice."""
    import asyncio

    store = await opened(tmp_path)
    for n in range(3000):  # several chunks
        await store["things"].insert({"_id": n, "v": 0})
    await store.flush()
    journal = store.journal  # type: ignore[attr-defined]
    compacting = asyncio.create_task(journal.compact(store._snapshot))  # type: ignore[attr-defined]
    turns = 0
    while not compacting.done() and turns < 1000:  # writes at the turns it gives back
        await store["things"].update({"_id": turns}, set={"v": 1})
        await store["things"].insert({"_id": 10_000 + turns, "v": 2})
        await store["things"].delete({"_id": 2999 - turns})
        turns += 1
        await asyncio.sleep(0)
    await compacting
    assert turns > 5  # the loop had turns while it encoded (six chunks and more)
    await store.flush()
    again = await opened(tmp_path)  # the first one "crashed": no close
    docs = {d["_id"]: d["v"] for d in await again["things"].find({})}
    expected = {n: (1 if n < turns else 0) for n in range(3000 - turns)}
    expected.update({10_000 + t: 2 for t in range(turns)})
    assert docs == expected
    await again.close()
