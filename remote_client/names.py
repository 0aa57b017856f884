"""Vehicles, zones and obstacles by id or by name: what a user types, resolved. Pure."""

from __future__ import annotations

from collections.abc import Sequence

from remote_client.sdk_session import Body, FleetApiError

__all__ = ["AmbiguousName", "UnknownVehicle", "pick_named", "pick_vehicle"]


class UnknownVehicle(FleetApiError):
    """No vehicle (nor instance) the caller can see goes by that id or name. Found by the
    client, not refused by the server: ``status`` 404 as the server's would be."""

    def __init__(self, ref: str, message: str | None = None) -> None:
        message = message or f"no vehicle with the id or name {ref!r} among those you can see"
        super().__init__(404, "not_found", message)
        self.ref = ref


class AmbiguousName(FleetApiError):
    """Several vehicles (zones, obstacles) go by that name: give an id (``details`` lists
    them)."""

    def __init__(self, ref: str, matches: Sequence[Body], kind: str = "vehicle") -> None:
        ids = ", ".join(v[f"{kind}_id"] for v in matches)
        super().__init__(
            409,
            "ambiguous_name",
            f"{len(matches)} {kind}s are named {ref!r} ({ids}): give a {kind} id",
            [{"field": kind, "message": v[f"{kind}_id"]} for v in matches],
        )
        self.ref = ref


def pick_vehicle(ref: str, fleet: Sequence[Body]) -> Body:
    """The vehicle whose id is ``ref``, else the one named ``ref`` (exactly, then ignoring
    case)."""
    return pick_named(ref, fleet, "vehicle")


def pick_named(ref: str, items: Sequence[Body], kind: str) -> Body:
    """The item (a ``kind``: vehicle, zone, obstacle) whose ``<kind>_id`` is ``ref``, else
    the one named ``ref`` (exactly, then ignoring case). None: :class:`UnknownVehicle` for
    a vehicle, a 404 :class:`FleetApiError` otherwise; several: :class:`AmbiguousName`."""
    for item in items:
        if item[f"{kind}_id"] == ref:
            return item
    named = [v for v in items if v.get("name") == ref]
    if not named:
        folded = ref.casefold()
        named = [v for v in items if str(v.get("name", "")).casefold() == folded]
    if len(named) > 1:
        raise AmbiguousName(ref, named, kind)
    if not named:
        if kind == "vehicle":
            raise UnknownVehicle(ref)
        raise FleetApiError(404, "not_found", f"no {kind} with the id or name {ref!r}")
    return named[0]
