"""A vehicle's parameters: the shallow merge of what it sends, within bounds. Pure."""

from __future__ import annotations

from typing import Any

from pydantic_core import to_json

from fleet_protocol import MAX_PARAMS, MAX_PARAMS_BYTES
from server.errors import Invalid

_ABSENT = object()


def params_after(
    held: dict[str, Any], params: dict[str, Any], *, starting: bool = False
) -> dict[str, Any] | None:
    """The parameters once ``params`` is merged into ``held`` (a ``null`` value deletes its
    key); None when that changes nothing. The result keeps to the bounds of one call's
    ``params`` (:data:`MAX_PARAMS` entries, :data:`MAX_PARAMS_BYTES` of JSON): past them,
    :class:`Invalid` naming ``params``, or, for a vehicle starting again (``starting``),
    the parameters it sends alone."""
    if not any(_changes(held.get(key, _ABSENT), value) for key, value in params.items()):
        return None
    merged = dict(held)
    for key, value in params.items():
        if value is None:
            merged.pop(key, None)
        else:
            merged[key] = value
    problem = _problem(merged)
    if problem is None:
        return merged
    if starting:
        return {k: v for k, v in params.items() if v is not None}
    raise Invalid(
        f"params: {problem}: delete some (a null value deletes a key)",
        details=[{"field": "params", "message": problem}],
    )


def _changes(held: Any, value: Any) -> bool:
    """Whether ``value`` is not what is held (``1`` and ``true`` are not the same JSON)."""
    return held != value or type(held) is not type(value)


def _problem(params: dict[str, Any]) -> str | None:
    if len(params) > MAX_PARAMS:
        return f"the vehicle would hold {len(params)} parameters; at most {MAX_PARAMS}"
    size = len(to_json(params))
    if size > MAX_PARAMS_BYTES:
        return f"the parameters would take {size} bytes of JSON; at most {MAX_PARAMS_BYTES}"
    return None
