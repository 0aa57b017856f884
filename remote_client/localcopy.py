"""A local SQLite copy of chosen vehicles' telemetry, kept up to date incrementally, for
work away from the server (``fleetctl sync``).

Each sample is stored once, keyed by ``(vehicle_id, seq)``. A sync asks the server
for the samples after the highest ``seq`` the copy holds for the vehicle, and
commits each page in one transaction as it comes: an interrupted sync leaves
whole pages behind, and the next one starts after the last of them. Nothing
else records how far a sync got, so the copy cannot disagree with itself.

Tables::

    samples(vehicle_id, seq, ts, lat, lon, depth_m, heading_deg, speed_mps,
            battery_pct, data)        -- data: the sample's data as JSON text
    vehicles(vehicle_id, name, vehicle_type, synced_at)

``ts`` is the contract's ISO 8601 text (UTC, milliseconds), which sorts in time order.
"""

from __future__ import annotations

import asyncio
import json
import sqlite3
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from fleet_protocol.common import format_ts
from remote_client.sdk import FleetClient

__all__ = ["COLUMNS", "LocalCopy", "SyncResult", "sync_vehicle"]

#: The sample's fields, as the copy's columns (``data`` after them, as JSON text).
COLUMNS = ("seq", "ts", "lat", "lon", "depth_m", "heading_deg", "speed_mps", "battery_pct")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS samples (
    vehicle_id TEXT NOT NULL,
    seq INTEGER NOT NULL,
    ts TEXT NOT NULL,
    lat REAL NOT NULL,
    lon REAL NOT NULL,
    depth_m REAL,
    heading_deg REAL,
    speed_mps REAL,
    battery_pct REAL,
    data TEXT,
    PRIMARY KEY (vehicle_id, seq)
) WITHOUT ROWID;
CREATE INDEX IF NOT EXISTS samples_by_time ON samples (vehicle_id, ts);
CREATE TABLE IF NOT EXISTS vehicles (
    vehicle_id TEXT PRIMARY KEY,
    name TEXT,
    vehicle_type TEXT,
    synced_at TEXT
);
"""


@dataclass(frozen=True)
class SyncResult:
    vehicle_id: str
    #: Samples this sync added to the copy.
    added: int
    #: Samples of the vehicle in the copy now, and the highest ``seq`` among them.
    total: int
    through_seq: int


class LocalCopy:
    """The SQLite file. Its calls are short; the async side runs them in a worker thread,
    one at a time."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
        self._db.executescript(_SCHEMA)

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> LocalCopy:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def high_seq(self, vehicle_id: str) -> int:
        """The highest ``seq`` held for the vehicle; 0 when none (``seq`` starts at 1)."""
        row = self._db.execute(
            "SELECT max(seq) FROM samples WHERE vehicle_id = ?", (vehicle_id,)
        ).fetchone()
        return int(row[0]) if row and row[0] is not None else 0

    def count(self, vehicle_id: str) -> int:
        row = self._db.execute(
            "SELECT count(*) FROM samples WHERE vehicle_id = ?", (vehicle_id,)
        ).fetchone()
        return int(row[0])

    def add_page(self, vehicle_id: str, samples: Sequence[dict[str, Any]]) -> int:
        """Store one page in one transaction; the number of samples new to the copy."""
        rows = [
            (
                vehicle_id,
                *(s.get(name) for name in COLUMNS),
                json.dumps(s["data"], separators=(",", ":")) if s.get("data") is not None else None,
            )
            for s in samples
        ]
        with self._transaction():
            before = self._db.total_changes
            self._db.executemany(
                "INSERT OR IGNORE INTO samples (vehicle_id, seq, ts, lat, lon, depth_m,"
                " heading_deg, speed_mps, battery_pct, data) VALUES (?,?,?,?,?,?,?,?,?,?)",
                rows,
            )
            return self._db.total_changes - before

    def note_vehicle(self, vehicle: dict[str, Any], synced_at: datetime) -> None:
        with self._transaction():
            self._db.execute(
                "INSERT INTO vehicles (vehicle_id, name, vehicle_type, synced_at)"
                " VALUES (?,?,?,?) ON CONFLICT (vehicle_id) DO UPDATE SET"
                " name = excluded.name, vehicle_type = excluded.vehicle_type,"
                " synced_at = excluded.synced_at",
                (
                    vehicle["vehicle_id"],
                    vehicle.get("name"),
                    vehicle.get("vehicle_type"),
                    format_ts(synced_at),
                ),
            )

    def samples(self, vehicle_id: str) -> list[dict[str, Any]]:
        """The vehicle's samples in ``seq`` order, as the server served them."""
        cursor = self._db.execute(
            f"SELECT {', '.join(COLUMNS)}, data FROM samples WHERE vehicle_id = ? ORDER BY seq",
            (vehicle_id,),
        )
        out = []
        for row in cursor:
            sample = {k: v for k, v in zip(COLUMNS, row, strict=False) if v is not None}
            if row[-1] is not None:
                sample["data"] = json.loads(row[-1])
            out.append(sample)
        return out

    def _transaction(self) -> _Transaction:
        return _Transaction(self._db)


class _Transaction:
    def __init__(self, db: sqlite3.Connection) -> None:
        self.db = db

    def __enter__(self) -> None:
        self.db.execute("BEGIN IMMEDIATE")

    def __exit__(self, kind: type[BaseException] | None, *rest: object) -> None:
        self.db.execute("COMMIT" if kind is None else "ROLLBACK")


async def sync_vehicle(
    fleet: FleetClient,
    copy: LocalCopy,
    vehicle: dict[str, Any],
    *,
    since: str | None = None,
    full: bool = False,
    page: int = 10_000,
    progress: Callable[[int], None] | None = None,
) -> SyncResult:
    """Bring the copy of one vehicle (its view, from ``GET /api/vehicles``) up to date:
    the samples after the highest ``seq`` held (``full``: every sample, those missing
    stored), from ``since`` on when given. ``progress`` hears the samples added so far."""
    vehicle_id = vehicle["vehicle_id"]
    after = 0 if full else await asyncio.to_thread(copy.high_seq, vehicle_id)
    added = 0
    async for samples in fleet.telemetry_pages(vehicle_id, since=since, page=page, after=after):
        added += await asyncio.to_thread(copy.add_page, vehicle_id, samples)
        if progress is not None:
            progress(added)
    await asyncio.to_thread(copy.note_vehicle, vehicle, datetime.now(UTC))
    total = await asyncio.to_thread(copy.count, vehicle_id)
    through = await asyncio.to_thread(copy.high_seq, vehicle_id)
    return SyncResult(vehicle_id, added, total, through)
