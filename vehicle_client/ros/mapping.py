"""ROS <-> fleet mapping, pure and stdlib-only (the bridge runs without pydantic).

ROS conventions: positions in ENU metres, yaw counter-clockwise from east
(REP 103). Fleet conventions: WGS84 degrees, heading clockwise from north.
"""

from __future__ import annotations

import json
import math
from typing import Any

from vehicle_client.geo import LocalFrame

#: Statuses the vehicle's own controller may report on the status topic.
REPORT_STATUSES = ("executing", "done", "failed")
#: NavSatFix status below this means no fix (sensor_msgs/NavSatStatus.STATUS_NO_FIX).
STATUS_FIX = 0


def yaw_to_heading_deg(x: float, y: float, z: float, w: float) -> float:
    """Compass heading of an ENU orientation quaternion."""
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return (90.0 - math.degrees(yaw)) % 360.0


def fix_fields(status: int, lat: float, lon: float) -> dict[str, float] | None:
    """Sample fields of a ``sensor_msgs/NavSatFix``; ``None`` without a usable fix."""
    if status < STATUS_FIX or not (math.isfinite(lat) and math.isfinite(lon)):
        return None
    if not (-90 <= lat <= 90 and -180 <= lon <= 180):
        return None
    return {"lat": lat, "lon": lon}


def pose_fields(
    datum: LocalFrame | None, x: float, y: float, z: float, q: tuple[float, float, float, float]
) -> dict[str, float]:
    """Sample fields of a ``geometry_msgs/PoseStamped`` in ENU metres around ``datum``."""
    fields: dict[str, float] = {"heading_deg": round(yaw_to_heading_deg(*q), 2) % 360.0}
    if datum is not None:
        fields["lat"], fields["lon"] = datum.to_latlon(x, y)
        if z < 0:
            fields["depth_m"] = -z
    return fields


class VehicleState:
    """The latest of each input, merged into one set of sample fields."""

    def __init__(self) -> None:
        self._fix: dict[str, float] | None = None
        self._pose: dict[str, float] = {}
        self._extra: dict[str, float] = {}
        self.local_control = False

    def on_fix(self, fields: dict[str, float] | None) -> None:
        self._fix = fields

    def on_pose(self, fields: dict[str, float]) -> None:
        self._pose = fields

    def on_battery(self, percentage: float) -> None:
        """``sensor_msgs/BatteryState.percentage`` is 0..1 (NaN when unknown)."""
        if math.isfinite(percentage):
            self._extra["battery_pct"] = max(0.0, min(100.0, percentage * 100.0))

    def fields(self) -> dict[str, float] | None:
        """Sample fields, the fix's position winning over the pose's; ``None`` without one."""
        merged = {**self._pose, **self._extra, **(self._fix or {})}
        return merged if "lat" in merged and "lon" in merged else None


def command_text(kind: str, args: dict[str, Any], command_id: str | None) -> str:
    """The ``std_msgs/String`` published on the command topic."""
    return json.dumps({"command_id": command_id, "type": kind, "args": args}, sort_keys=True)


def parse_status(text: str) -> dict[str, Any] | None:
    """A report from the status topic: ``{"type", "status", "progress"?, "detail"?}``."""
    try:
        msg = json.loads(text)
    except ValueError:
        return None
    if not isinstance(msg, dict) or msg.get("status") not in REPORT_STATUSES:
        return None
    if not isinstance(msg.get("type"), str):
        return None
    progress = msg.get("progress")
    if progress is not None and not (isinstance(progress, int | float) and 0 <= progress <= 1):
        progress = None
    detail = msg.get("detail")
    return {
        "kind": msg["type"],
        "status": msg["status"],
        "progress": progress,
        "detail": str(detail)[:512] if detail is not None else None,
    }


def encode(message: dict[str, Any]) -> bytes:
    """One line of the bridge protocol."""
    return (json.dumps(message, separators=(",", ":")) + "\n").encode()


def decode(line: bytes) -> dict[str, Any] | None:
    try:
        message = json.loads(line)
    except ValueError:
        return None
    return message if isinstance(message, dict) and isinstance(message.get("op"), str) else None
