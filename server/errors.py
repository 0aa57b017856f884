"""One error hierarchy: every failure the contract names carries a code and a status.

The domain and services raise these; one handler in ``server.api.errors``
renders them as the contract's envelope. Nothing here knows about HTTP beyond
the status number.
"""

from __future__ import annotations

from typing import Any


class FleetError(Exception):
    status = 400
    code = "invalid"

    def __init__(self, message: str, *, details: Any = None, code: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.details = details
        if code is not None:
            self.code = code


class Unauthorized(FleetError):
    status = 401
    code = "unauthorized"


class Forbidden(FleetError):
    status = 403
    code = "forbidden"


class NotFound(FleetError):
    status = 404
    code = "not_found"


class Conflict(FleetError):
    status = 409
    code = "conflict"


class ControlNotHeld(Conflict):
    code = "control_not_held"


class VehicleLocalControl(Conflict):
    code = "vehicle_local_control"


class InstanceFinished(Conflict):
    code = "instance_finished"


class Invalid(FleetError):
    status = 422
    code = "invalid"


class CapabilityMissing(Invalid):
    code = "capability_missing"


class ZoneViolation(Invalid):
    """A target or a route in a no-go zone, or out of the vehicle's operating area."""

    code = "zone_violation"

    def __init__(self, message: str, *, zone_id: str = "", zone: str = "", kind: str = "") -> None:
        self.zone = {"zone_id": zone_id, "zone": zone, "zone_kind": kind}
        super().__init__(
            message, details=[{"field": "command.args", "message": message, **self.zone}]
        )


class RateLimited(FleetError):
    status = 429
    code = "rate_limited"

    def __init__(self, message: str, *, retry_after_s: float = 1.0, details: Any = None) -> None:
        super().__init__(message, details=details)
        self.retry_after_s = retry_after_s


class Unavailable(FleetError):
    status = 503
    code = "unavailable"

    def __init__(self, message: str, *, retry_after_s: float = 2.0) -> None:
        super().__init__(message)
        self.retry_after_s = retry_after_s
