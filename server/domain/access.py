"""Who may do what: roles, vehicle access. Pure."""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime
from typing import Literal

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

    def acts_for(self, vehicle_id: str) -> bool:
        """A vehicle token acts for its vehicle; a gateway token for those it lists."""
        if self.kind == "vehicle":
            return vehicle_id == self.name
        if self.kind == "gateway":
            return vehicle_id in self.vehicles
        return False

    def label(self) -> str:
        return self.name if self.kind == "user" else f"{self.kind}:{self.name}"
