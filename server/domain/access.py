"""Who may do what: roles, vehicle access. Pure."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any, Literal

PrincipalKind = Literal["user", "vehicle", "gateway"]
ROLE_RANK = {"viewer": 0, "operator": 1, "manager": 2, "admin": 3}


@dataclass(frozen=True)
class Principal:
    """The authenticated caller of one request or socket."""

    kind: PrincipalKind
    name: str
    role: str | None = None  # users only
    vehicles: frozenset[str] = field(default_factory=frozenset)
    token_id: str = ""
    #: When the token stops being valid (a session's); None: until revoked.
    expires_at: datetime | None = None

    @property
    def is_admin(self) -> bool:
        return self.kind == "user" and self.role == "admin"

    def at_least(self, role: str) -> bool:
        return self.kind == "user" and ROLE_RANK.get(self.role or "", -1) >= ROLE_RANK[role]

    def can_see(self, vehicle_id: str) -> bool:
        if self.kind == "vehicle":
            return vehicle_id == self.name
        return self.is_admin or vehicle_id in self.vehicles

    def reads_vehicle(self, vehicle_id: str) -> bool:
        """Whether it reads what the vehicle produces: it sees the vehicle or acts for it."""
        return self.can_see(vehicle_id) or self.acts_for(vehicle_id)

    def acts_for(self, vehicle_id: str) -> bool:
        """A vehicle token acts for its vehicle; a gateway token for those it lists."""
        if self.kind == "vehicle":
            return vehicle_id == self.name
        if self.kind == "gateway":
            return vehicle_id in self.vehicles
        return False

    def label(self) -> str:
        return self.name if self.kind == "user" else f"{self.kind}:{self.name}"


def zone_vehicles_seen(listed: Sequence[str], who: Principal) -> list[str] | None:
    """Of a zone's ``listed`` vehicles, those ``who`` sees; None when it lists vehicles and
    they see none of them (the zone is not theirs to see). A zone that lists none concerns
    every vehicle, and everyone sees it."""
    seen = [v for v in listed if who.can_see(v)]
    return None if listed and not seen else seen


def enabled_admin(user: Mapping[str, Any]) -> bool:
    """Whether a stored user is an admin who can sign in."""
    return user.get("role") == "admin" and not user.get("disabled")


def unseats_admin(user: Mapping[str, Any], role: str | None, disabled: bool | None) -> bool:
    """Whether a change of ``role`` or ``disabled`` (None: unchanged) leaves an enabled
    admin without the admin's rights. The last one may not lose them: nobody could
    give them back."""
    return enabled_admin(user) and ((role is not None and role != "admin") or bool(disabled))
