"""The durable outbox: telemetry kept on the vehicle until the server has it for good.

One SQLite file (``--outbox``) holds three tables:

- ``samples``: every sample, numbered with the next ``seq``, written here
  before anything is sent, and deleted only once the server reports it
  durable (``durable_through_seq``). Sending drains it oldest first.
- ``seen``: every ``command_id`` the agent has seen and its last status, so
  that a command delivered again, even after a restart, is not carried out
  twice.
- ``meta``: the vehicle it belongs to, the next ``seq``, whether it was
  matched with the server's ``last_seq`` yet, and how many samples were
  dropped and refused.

An outbox is one vehicle's: its ``seq`` numbering and its samples are that
vehicle's. The first vehicle to open it owns it (an outbox an older version
wrote, with no owner yet, goes to the first that opens it now), and any other
is refused (:class:`OutboxTaken`): two agents started in one folder without
``--outbox`` would otherwise send each other's positions as their own.

A sample is checked with the wire model (``fleet_protocol.Sample``, under
the ``seq`` it gets) before it is stored: one the server would refuse (a
value JSON or the store cannot hold, ``docs/limits.md``) would block the
queue behind it for good, so it is refused here instead: logged with its
``seq`` and the fields at fault (never the whole payload), counted in
``refused``, its ``seq`` left unused. :meth:`Outbox.refuse` takes out rows
stored before a rule existed, when the wire model refuses them on sending.

Bound: at most ``max_samples`` rows (default 172,800: two days at 1 Hz,
nearly ten hours at 5 Hz). Past it the OLDEST samples are dropped, counted
in ``dropped`` (kept in the file) and logged: at sea the newest position
matters most. ``seen`` keeps the newest ``max_seen`` ids.

The class is synchronous (stdlib ``sqlite3``, one connection behind a
lock); the daemon calls it through ``asyncio.to_thread``. The file uses
WAL with ``synchronous=NORMAL``: a killed agent loses nothing committed; a
power cut may lose the last moments.
"""

from __future__ import annotations

import fcntl
import json
import logging
import os
import sqlite3
import threading
import time
from collections.abc import Iterator, MutableMapping
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from fleet_protocol import Sample
from fleet_protocol.ws_frames import field_errors
from vehicle_client.errors import FatalError

log = logging.getLogger(__name__)

DEFAULT_MAX_SAMPLES = 172_800
DEFAULT_MAX_SEEN = 20_000
UNFINISHED = ("accepted", "executing")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS samples (seq INTEGER PRIMARY KEY, body TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS seen (
    command_id TEXT PRIMARY KEY, status TEXT NOT NULL, updated_at REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS seen_by_age ON seen (updated_at);
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
"""


def _private_file(path: Path) -> None:
    """The outbox's folder (made if missing, owner-only) and file, owner-only whatever
    mode an older version left; SQLite gives its journal files the file's own mode."""
    path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
    try:
        os.fchmod(fd, 0o600)
    finally:
        os.close(fd)


class OutboxUnusable(FatalError):
    """The outbox's file cannot be made or opened (no permission, a folder, a read-only
    file system): the agent cannot keep a sample it takes, so it does not start."""


class OutboxTaken(FatalError):
    """The outbox belongs to another vehicle."""

    def __init__(self, path: Path, owner: str, vehicle_id: str) -> None:
        super().__init__(
            f"the outbox {path} holds vehicle {owner}'s samples: give vehicle {vehicle_id} "
            "its own (--outbox, or outbox in its config file)"
        )
        self.owner = owner


class OutboxInUse(FatalError):
    """Another process has the outbox open for its vehicle."""

    def __init__(self, path: Path, holder: str) -> None:
        by = f"process {holder}" if holder.isdigit() else "another process"
        super().__init__(
            f"the outbox {path} is in use by {by}: stop that agent, or give this one "
            "its own outbox (--outbox, or outbox in its config file)"
        )


def _hold(path: Path) -> int:
    """The lock beside ``path``, held (its file descriptor), with this process's id in
    it; :class:`OutboxInUse` when another holds it."""
    lock = path.with_name(path.name + ".lock")
    fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.pread(fd, 20, 0).decode(errors="replace").strip()
        os.close(fd)
        raise OutboxInUse(path, holder) from None
    except BaseException:
        os.close(fd)
        raise
    os.ftruncate(fd, 0)
    os.pwrite(fd, str(os.getpid()).encode(), 0)
    return fd


class Outbox:
    def __init__(
        self,
        path: str | Path,
        max_samples: int = DEFAULT_MAX_SAMPLES,
        max_seen: int = DEFAULT_MAX_SEEN,
        *,
        vehicle_id: str | None = None,
    ) -> None:
        """``vehicle_id``: the vehicle it is for (:class:`OutboxTaken` if another owns it,
        :class:`OutboxInUse` if another process has it open for one; None: neither
        checked, as in tests of the outbox alone)."""
        if max_samples < 1 or max_seen < 1:
            raise ValueError("max_samples and max_seen must be at least 1")
        self.path = Path(path)
        self.max_samples = max_samples
        self.max_seen = max_seen
        self._lock = threading.Lock()
        self._held: int | None = None
        try:
            if str(path) != ":memory:":
                _private_file(self.path)
                if vehicle_id is not None:
                    self._held = _hold(self.path)
            self._db = sqlite3.connect(str(path), check_same_thread=False, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=NORMAL")
            self._db.executescript(_SCHEMA)
        except (OSError, sqlite3.Error) as exc:
            self._let_go()
            why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            raise OutboxUnusable(f"the outbox {path} cannot be opened: {why}") from None
        if vehicle_id is not None:
            self._claim(vehicle_id)
        self._count = self._db.execute("SELECT COUNT(*) FROM samples").fetchone()[0]
        self.seen = SeenCommands(self)

    def _claim(self, vehicle_id: str) -> None:
        """Own the outbox for ``vehicle_id`` unless another vehicle does (one statement:
        of two agents opening it at once, one owns it)."""
        self._db.execute(
            "INSERT OR IGNORE INTO meta (key, value) VALUES ('vehicle_id', ?)", (vehicle_id,)
        )
        owner = self._db.execute("SELECT value FROM meta WHERE key = 'vehicle_id'").fetchone()[0]
        if owner != vehicle_id:
            self._db.close()
            self._let_go()
            raise OutboxTaken(self.path, owner, vehicle_id)

    def close(self) -> None:
        with self._lock:
            self._db.close()
            self._let_go()

    def _let_go(self) -> None:
        if self._held is not None:
            os.close(self._held)  # the lock goes with it
            self._held = None

    # -- meta --------------------------------------------------------------
    def _meta(self, key: str, default: int) -> int:
        row = self._db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return int(row[0]) if row else default

    def _set_meta(self, key: str, value: int) -> None:
        self._db.execute(
            "INSERT INTO meta (key, value) VALUES (?, ?) "
            "ON CONFLICT(key) DO UPDATE SET value = excluded.value",
            (key, str(value)),
        )

    @property
    def next_seq(self) -> int:
        with self._lock:
            return self._meta("next_seq", 1)

    @property
    def dropped(self) -> int:
        with self._lock:
            return self._meta("dropped", 0)

    @property
    def refused(self) -> int:
        """Samples refused by the wire model (never stored, or taken out unsent)."""
        with self._lock:
            return self._meta("refused", 0)

    @property
    def pending(self) -> int:
        with self._lock:
            return self._count

    def oldest_seq(self) -> int | None:
        with self._lock:
            return self._db.execute("SELECT MIN(seq) FROM samples").fetchone()[0]

    # -- samples -------------------------------------------------------------
    def match_server(self, last_seq: int) -> None:
        """Number from above the server's ``last_seq`` (``start_instance``).

        The first time (a fresh install, or an outbox that filled while the
        server was never reached), the samples not yet sent are renumbered
        to follow ``last_seq``; afterwards numbering only ever moves up.
        """
        with self._lock, self._tx():
            next_seq = self._meta("next_seq", 1)
            if not self._meta("matched", 0):
                low = self._db.execute("SELECT MIN(seq) FROM samples").fetchone()[0]
                if low is not None and low <= last_seq:
                    shift = last_seq + 1 - low
                    # Negative first, then back, so no key collides mid-update.
                    self._db.execute("UPDATE samples SET seq = -(seq + ?)", (shift,))
                    self._db.execute("UPDATE samples SET seq = -seq")
                    self._db.execute("UPDATE samples SET body = json_set(body, '$.seq', seq)")
                    next_seq += shift
                self._set_meta("matched", 1)
            self._set_meta("next_seq", max(next_seq, last_seq + 1))

    def append(self, sample: dict[str, Any]) -> int | None:
        """Store one sample under the next ``seq`` and answer that ``seq``; ``None`` when
        the wire model refuses it (logged with that ``seq``, counted in :attr:`refused`)."""
        with self._lock, self._tx():
            seq = self._meta("next_seq", 1)
            self._set_meta("next_seq", seq + 1)
            numbered = {**sample, "seq": seq}
            try:
                Sample.model_validate(numbered)
            except ValidationError as exc:
                self._count_refused([seq], _reasons(exc))
                return None
            body = json.dumps(numbered, separators=(",", ":"), default=str)
            self._db.execute("INSERT INTO samples (seq, body) VALUES (?, ?)", (seq, body))
            self._count += 1
            if self._count > self.max_samples:
                self._drop_oldest(self._count - self.max_samples)
        return seq

    def _drop_oldest(self, n: int) -> None:
        self._db.execute(
            "DELETE FROM samples WHERE seq IN (SELECT seq FROM samples ORDER BY seq LIMIT ?)",
            (n,),
        )
        self._count -= n
        total = self._meta("dropped", 0) + n
        self._set_meta("dropped", total)
        if total == n or total % 1000 < n:
            log.warning(
                "outbox full (%d samples): dropped the oldest, %d dropped so far",
                self.max_samples,
                total,
            )

    def refuse(self, seqs: list[int], reason: str) -> None:
        """Take out stored samples the wire model refuses (stored by an older version):
        logged with their ``seq``, counted in :attr:`refused`."""
        with self._lock, self._tx():
            n = self._db.executemany("DELETE FROM samples WHERE seq = ?", [(s,) for s in seqs])
            self._count -= n.rowcount
            self._count_refused(seqs, reason)

    def _count_refused(self, seqs: list[int], reason: str) -> None:
        total = self._meta("refused", 0) + len(seqs)
        self._set_meta("refused", total)
        shown = ", ".join(str(s) for s in seqs[:10]) + (", ..." if len(seqs) > 10 else "")
        log.error("sample seq %s refused, not sent (%d refused so far): %s", shown, total, reason)

    def batch(self, after_seq: int = 0, limit: int = 500) -> list[dict[str, Any]]:
        """The oldest samples above ``after_seq``, at most ``limit``."""
        with self._lock:
            rows = self._db.execute(
                "SELECT body FROM samples WHERE seq > ? ORDER BY seq LIMIT ?",
                (after_seq, limit),
            ).fetchall()
        return [json.loads(r[0]) for r in rows]

    def confirm_durable(self, through_seq: int) -> int:
        """The server keeps everything up to ``through_seq``: forget it here."""
        with self._lock, self._tx():
            n = self._db.execute("DELETE FROM samples WHERE seq <= ?", (through_seq,)).rowcount
            self._count -= n
        return n

    # -- plumbing --------------------------------------------------------------
    def _tx(self) -> _Transaction:
        return _Transaction(self._db)


def _reasons(exc: ValidationError) -> str:
    """The fields at fault and why, without the values (a reading may be large)."""
    return "; ".join(f"{e.field}: {e.message}" for e in field_errors(exc)[:5])


class _Transaction:
    def __init__(self, db: sqlite3.Connection) -> None:
        self.db = db

    def __enter__(self) -> None:
        self.db.execute("BEGIN IMMEDIATE")

    def __exit__(self, exc_type: object, *_: object) -> None:
        self.db.execute("ROLLBACK" if exc_type else "COMMIT")


class SeenCommands(MutableMapping[str, str]):
    """``command_id`` -> last status, persisted in the outbox file."""

    def __init__(self, outbox: Outbox) -> None:
        self._o = outbox

    def __getitem__(self, command_id: str) -> str:
        with self._o._lock:
            row = self._o._db.execute(
                "SELECT status FROM seen WHERE command_id = ?", (command_id,)
            ).fetchone()
        if row is None:
            raise KeyError(command_id)
        return row[0]

    def __setitem__(self, command_id: str, status: str) -> None:
        o = self._o
        with o._lock, o._tx():
            o._db.execute(
                "INSERT INTO seen (command_id, status, updated_at) VALUES (?, ?, ?) "
                "ON CONFLICT(command_id) DO UPDATE SET status = excluded.status, "
                "updated_at = excluded.updated_at",
                (command_id, status, time.time()),
            )
            over = o._db.execute("SELECT COUNT(*) FROM seen").fetchone()[0] - o.max_seen
            if over > 0:
                o._db.execute(
                    "DELETE FROM seen WHERE command_id IN "
                    "(SELECT command_id FROM seen ORDER BY updated_at, rowid LIMIT ?)",
                    (over,),
                )

    def __delitem__(self, command_id: str) -> None:
        with self._o._lock:
            self._o._db.execute("DELETE FROM seen WHERE command_id = ?", (command_id,))

    def __iter__(self) -> Iterator[str]:
        with self._o._lock:
            rows = self._o._db.execute("SELECT command_id FROM seen").fetchall()
        return iter([r[0] for r in rows])

    def __len__(self) -> int:
        with self._o._lock:
            return self._o._db.execute("SELECT COUNT(*) FROM seen").fetchone()[0]

    def unfinished(self) -> list[str]:
        """Ids last reported ``accepted`` or ``executing``."""
        with self._o._lock:
            rows = self._o._db.execute(
                "SELECT command_id FROM seen WHERE status IN (?, ?) ORDER BY updated_at",
                UNFINISHED,
            ).fetchall()
        return [r[0] for r in rows]
