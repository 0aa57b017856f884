"""Durability for the embedded store: a base snapshot plus a write-ahead journal.

Every write the embedded store makes is encoded here first (BSON; a record
BSON cannot hold is refused before anything changes), kept in memory, and
appended to ``<snapshot>.journal`` by :meth:`Journal.flush`, fsynced. On
start the base snapshot is loaded and the journal replayed; then both are
compacted into a new base. A flush costs only what was written since the
last one, so it can run every few seconds with a million samples stored.

Both files begin with a generation number. A compaction writes the new base
(generation N + 1) to a temporary file and renames it over the old one, then
starts a new journal the same way. A crash between the two renames leaves a
journal of generation N beside a base of N + 1: its writes are in the base
already, and it is skipped. A compaction that fails leaves the previous base
and journal as they were, and the writes it would have folded in stay
pending for the next flush.

The files hold every user, token digest and password hash: they are made
readable by their owner only (0600), and the folder, when made here, too
(0700). A folder that exists already is left as it is (it may be shared);
a file a former version made with other modes is set to 0600 when next
written.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, BinaryIO

import bson

log = logging.getLogger("fleet.storage")

_CODEC: bson.CodecOptions[Any] = bson.CodecOptions(tz_aware=False)
#: Documents per snapshot entry.
_CHUNK = 500

Replay = Callable[[dict[str, Any]], None]
Snapshot = Callable[[], Iterator[tuple[str, list[dict[str, Any]]]]]

#: The data files: the owner reads and writes them, nobody else.
FILE_MODE = 0o600
#: The folder they are in, when it is made here.
DIR_MODE = 0o700


def _private_dir(path: Path) -> None:
    """Make ``path`` (and its parents) if missing; the last one owner-only."""
    path.mkdir(mode=DIR_MODE, parents=True, exist_ok=True)


def _open_private(path: Path, *, append: bool) -> BinaryIO:
    """``path`` opened for writing (appending or from empty), owner-only whatever mode it
    had (a file an older version made, created under any umask)."""
    flags = os.O_WRONLY | os.O_CREAT | (os.O_APPEND if append else os.O_TRUNC)
    fd = os.open(path, flags, FILE_MODE)
    try:
        os.fchmod(fd, FILE_MODE)
        return os.fdopen(fd, "ab" if append else "wb")
    except BaseException:
        os.close(fd)
        raise


def _entries(path: Path) -> Iterator[dict[str, Any]]:
    if not path.exists():
        return
    with path.open("rb") as fh:
        try:
            yield from bson.decode_file_iter(fh, _CODEC)
        except bson.errors.InvalidBSON:
            # A crash may leave a torn last entry: everything before it is kept.
            log.warning("%s ends in a torn entry; it is ignored", path)


def _write_file(path: Path, chunks: list[bytes]) -> None:
    """``path`` replaced whole by ``chunks``: written to a temporary file, fsynced, renamed."""
    new = _NewFile(path)
    try:
        for chunk in chunks:
            new.write(chunk)
    except BaseException:
        new.drop()
        raise
    new.finish()


class _NewFile:
    """A file that replaces ``path`` whole: written to a temporary file beside it, then
    fsynced and renamed over it (:meth:`finish`), or given up (:meth:`drop`)."""

    def __init__(self, path: Path) -> None:
        _private_dir(path.parent)
        self.path = path
        self.tmp = path.with_name(path.name + ".tmp")
        self.fh = _open_private(self.tmp, append=False)

    def write(self, chunk: bytes) -> None:
        self.fh.write(chunk)

    def size(self) -> int:
        return self.fh.tell()

    def drop(self) -> None:
        """Closed and removed; ``path`` stays as it was."""
        self.fh.close()
        with contextlib.suppress(OSError):
            os.unlink(self.tmp)

    def finish(self) -> None:
        """Fsynced and renamed over ``path`` (given up if that fails)."""
        try:
            self.fh.flush()
            os.fsync(self.fh.fileno())
            self.fh.close()
            os.replace(self.tmp, self.path)
        except BaseException:
            self.drop()
            raise
        dir_fd = os.open(self.path.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)


class Journal:
    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.journal_path = self.path.with_name(self.path.name + ".journal")
        self.rejected_path = self.path.with_name(self.path.name + ".rejected")
        self._pending: list[bytes] = []
        self._lock = asyncio.Lock()
        self.generation = 0
        self._journal_started = False
        #: Bytes in the base, and appended to the journal since it was last folded in.
        self.base_bytes = 0
        self.journal_bytes = 0

    @staticmethod
    def encode(op: str, coll: str, **fields: Any) -> bytes:
        """One entry: raises what BSON raises for a value it cannot hold."""
        entry: dict[str, Any] = {"o": op, "c": coll}
        if "docs" in fields:
            entry["d"] = fields["docs"]
        if "flt" in fields:
            entry["f"] = dict(fields["flt"])
        if "update" in fields:
            entry["u"] = dict(fields["update"])
        if fields.get("upsert"):
            entry["up"] = True
        return bson.encode(entry)

    def append(self, entry: bytes) -> None:
        self._pending.append(entry)

    @property
    def pending(self) -> int:
        return len(self._pending)

    async def flush(self) -> bool:
        """Append what was recorded since the last flush to the journal, fsynced.
        A failure leaves it pending (and raises)."""
        async with self._lock:
            if not self._pending:
                return False
            count = len(self._pending)
            data = b"".join(self._pending[:count])
            if not self._journal_started:
                data = bson.encode({"gen": self.generation}) + data
            await asyncio.to_thread(self._append, data, not self._journal_started)
            self._journal_started = True
            self.journal_bytes += len(data)
            del self._pending[:count]
            return True

    def outgrown(self, floor_bytes: int) -> bool:
        """Whether the journal is worth folding into the base: past ``floor_bytes`` and
        twice the base (a restart replays all of it, and deletions grow it too)."""
        return self.journal_bytes > max(floor_bytes, 2 * self.base_bytes)

    def _append(self, data: bytes, fresh: bool) -> None:
        _private_dir(self.path.parent)
        with _open_private(self.journal_path, append=not fresh) as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())

    async def restore(self, replay: Replay, snapshot: Snapshot) -> dict[str, int]:
        """Load the base, replay its journal, then compact. Each entry that fails is
        logged and written to ``<snapshot>.rejected``; the rest goes on."""
        counts: Counter[str] = Counter()
        base_gen: int | None = None
        for entry in _entries(self.path):
            if "gen" in entry:
                base_gen = int(entry["gen"])
                continue
            if self._replay_one(replay, {"o": "insert", "c": entry["c"], "d": entry["d"]}):
                counts[entry["c"]] += len(entry["d"])
            else:
                counts["rejected"] += 1
        replayed = 0
        journal = _entries(self.journal_path)
        first = next(journal, None)
        journal_gen = int(first["gen"]) if first is not None and "gen" in first else None
        if journal_gen is not None and journal_gen != (base_gen or 0):
            log.info(
                "journal generation %s is folded into the base (%s) already: skipped",
                journal_gen,
                base_gen,
            )
        elif first is not None:  # a journal of this base (or of a former version: no header)
            for entry in [first, *journal] if journal_gen is None else journal:
                if self._replay_one(replay, entry):
                    replayed += 1
                else:
                    counts["rejected"] += 1
        self.generation = base_gen or 0
        if self.path.exists():
            self.base_bytes = self.path.stat().st_size
        if counts or replayed:
            await self.compact(snapshot)
        return dict(counts) | ({"journal_entries": replayed} if replayed else {})

    def _replay_one(self, replay: Replay, entry: dict[str, Any]) -> bool:
        try:
            replay(entry)
        except Exception as exc:
            log.error(
                "restore: a stored %s on %s failed (%r): set aside",
                entry.get("o"),
                entry.get("c"),
                exc,
            )
            try:
                _private_dir(self.path.parent)
                with _open_private(self.rejected_path, append=True) as fh:
                    fh.write(bson.encode({"error": repr(exc), "entry": entry}))
            except Exception:
                log.exception("restore: the rejected entry could not be written aside")
            return False
        return True

    async def compact(self, snapshot: Snapshot) -> None:
        """Write every collection into a new base and start a new, empty journal."""
        async with self._lock:
            generation = self.generation + 1
            # The documents are taken at once (no write comes in between), then encoded a
            # chunk at a time with the event loop let go between chunks: a store of
            # hundreds of thousands of documents held every socket up for the whole of it.
            # A write made meanwhile replaces a document, never changes one in place, so
            # what was taken stays as it was.
            # Each chunk goes to the new base's file as it is made: the encoded store is
            # never held whole in memory.
            taken = list(snapshot())
            folded = len(self._pending)  # recorded before the snapshot: in it
            base = _NewFile(self.path)
            try:
                base.write(bson.encode({"gen": generation}))
                for name, docs in taken:
                    for chunk in _chunks(name, docs):
                        base.write(chunk)
                        await asyncio.sleep(0)
            except BaseException:
                base.drop()
                raise
            del taken
            base_bytes = base.size()
            await asyncio.to_thread(base.finish)
            self.generation = generation
            header = bson.encode({"gen": generation})
            await asyncio.to_thread(_write_file, self.journal_path, [header])
            self._journal_started = True
            self.base_bytes = base_bytes
            self.journal_bytes = len(header)
            del self._pending[:folded]


def _chunks(name: str, docs: list[dict[str, Any]]) -> Iterator[bytes]:
    for i in range(0, len(docs), _CHUNK):
        part = docs[i : i + _CHUNK]
        try:
            yield bson.encode({"c": name, "d": part})
        except Exception:
            # Never expected (every write was encoded before it was made): keep the rest.
            for doc in part:
                try:
                    yield bson.encode({"c": name, "d": [doc]})
                except Exception as exc:
                    log.error("snapshot: a document of %s cannot be encoded (%r)", name, exc)
