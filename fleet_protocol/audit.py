"""The control log: per vehicle, one append-only chain of entries, each carrying the hash
of the one before (``GET /api/vehicles/{vehicle_id}/audit``; ``fleetctl audit verify``).

An entry's ``hash`` is SHA-256 over the previous entry's hash and the entry's own
fields, written canonically (:func:`entry_hash`): change, remove or reorder one stored
entry and every later link stops matching.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from typing import Any

from fleet_protocol.common import Timestamp, WireModel
from fleet_protocol.served import ServedObject
from fleet_protocol.text import Text

__all__ = ["GENESIS", "AuditEntry", "AuditPage", "entry_hash", "first_break"]

#: The ``prev_hash`` of a vehicle's first entry.
GENESIS = "sha256:" + "0" * 64
#: The fields an entry's hash covers, in this order.
HASHED = ("vehicle_id", "seq", "at", "kind", "actor", "data")


class AuditEntry(WireModel):
    vehicle_id: Text
    seq: int
    at: Timestamp
    kind: Text
    actor: Text | None = None
    data: ServedObject
    prev_hash: Text
    hash: Text


class AuditPage(WireModel):
    entries: list[AuditEntry]
    next_after_seq: int | None


def entry_hash(prev_hash: str, entry: Mapping[str, Any]) -> str:
    """The hash of ``entry`` (its :data:`HASHED` fields, ``at`` as the contract writes
    times) chained to ``prev_hash``."""
    body = {name: entry.get(name) for name in HASHED}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=True, default=str)
    return "sha256:" + hashlib.sha256((prev_hash + "\n" + text).encode()).hexdigest()


def first_break(entries: Sequence[Mapping[str, Any]]) -> tuple[int, str] | None:
    """Where a chain (entries in ``seq`` order, ``at`` as wire text) breaks: the ``seq``
    of the first entry that does not match, and why; None when every link holds."""
    prev, expected_seq = GENESIS, None
    for entry in entries:
        seq = int(entry["seq"])
        if expected_seq is not None and seq != expected_seq:
            return seq, f"entry {expected_seq} is missing"
        if entry["prev_hash"] != prev:
            return seq, "its prev_hash is not the previous entry's hash"
        if entry_hash(prev, entry) != entry["hash"]:
            return seq, "its content does not match its hash"
        prev, expected_seq = entry["hash"], seq + 1
    return None
