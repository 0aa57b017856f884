"""The embedded store's document tables, reached by ``_id`` without a scan.

mongomock answers every query by scanning its whole collection, so a write
keyed by ``_id`` costs what the collection holds. Where the repositories know
the ``_id`` they go straight to mongomock's table (``_id`` -> document)
through this module, the one place that reaches inside mongomock(-motor).
Anything unexpected and the caller falls back to ordinary queries.
"""

from __future__ import annotations

import copy
import logging
from datetime import UTC, datetime
from typing import Any

from bson import ObjectId
from mongomock.helpers import patch_datetime_awareness_in_document

log = logging.getLogger("fleet.storage")
_NEEDED = ("documents", "__getitem__", "__setitem__", "__delitem__", "__contains__")


def table_of(raw_collection: Any) -> Any | None:
    """mongomock's table behind a mongomock-motor collection, or None."""
    inner = getattr(raw_collection, "__dict__", {}).get("_AsyncMongoMockCollection__collection")
    table = getattr(inner, "_store", None)
    if table is None or not all(hasattr(table, name) for name in _NEEDED):
        log.warning("embedded store internals not recognised: keyed access will scan")
        return None
    return table


def set_fields(table: Any, _id: Any, fields: dict[str, Any]) -> bool:
    """``$set`` of top-level fields on the document ``_id``; False when it is not there."""
    if _id not in table:
        return False
    # Stored the way mongomock stores them: datetimes naive UTC, millisecond precision.
    table[_id].update(patch_datetime_awareness_in_document(fields))
    return True


def insert(table: Any, doc: dict[str, Any]) -> bool:
    """Store ``doc`` as mongomock would (``_id`` filled in), for a collection with no
    unique index; False when its ``_id`` is taken. Skips mongomock's trial BSON
    encoding and unique-index pass, which cost more than the write itself."""
    if "_id" not in doc:
        doc["_id"] = ObjectId()
    if doc["_id"] in table:
        return False
    table[doc["_id"]] = patch_datetime_awareness_in_document(doc)
    return True


def read(table: Any, _id: Any) -> dict[str, Any] | None:
    """A copy of the document ``_id`` as the driver would return it (UTC-aware datetimes)."""
    if _id not in table:
        return None
    doc: dict[str, Any] = _aware(copy.deepcopy(table[_id]))
    return doc


def _aware(value: Any) -> Any:
    if isinstance(value, datetime):
        return value.replace(tzinfo=UTC) if value.tzinfo is None else value
    if isinstance(value, dict):
        return {k: _aware(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_aware(v) for v in value]
    return value
