"""What is wrong with a vehicle now, in words (``VehicleView.alarms``). Pure.

From its watch state (:mod:`server.domain.watch`: the zones it is in breach of, a low
battery) and the mode it reports (failsafe), most urgent first; each says since when it
is so (``since``; None when not known).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from datetime import datetime

from fleet_protocol import Alarm


def alarms_of(
    failsafe_action: str | None,
    breaches: Iterable[tuple[str, str, str | None, datetime | None]],
    battery: tuple[float | None, float | None, datetime | None] | None,
    failsafe_since: datetime | None = None,
) -> list[Alarm]:
    """``failsafe_action``: the policy's action while the vehicle is in failsafe (None:
    it is not), since ``failsafe_since``; ``breaches``: ``(zone_kind, zone_name, zone_id,
    since)`` of each zone breached; ``battery``: ``(reading, threshold, since)`` while the
    battery is low (None: it is not)."""
    out = []
    if failsafe_action is not None:
        said = f"in failsafe: {failsafe_action.replace('_', ' ')}"
        out.append(Alarm(kind="failsafe", message=said, since=failsafe_since))
    for zone_kind, name, zone_id, since in breaches:
        if zone_kind == "operating_area":
            kind, message = "outside_area", f"outside its operating area {name}"
        else:
            kind, message = "no_go_zone", f"inside no-go zone {name}"
        out.append(Alarm(kind=kind, message=message.rstrip(), zone_id=zone_id, since=since))
    if battery is not None:
        pct, threshold, since = battery
        out.append(Alarm(kind="low_battery", message=_battery_text(pct, threshold), since=since))
    return out


def _battery_text(pct: float | None, threshold: float | None) -> str:
    # to a tenth, down: a reading below the threshold never reads as at it
    reading = f": {math.floor(float(pct) * 10) / 10:g} %" if pct is not None else ""
    below = f" (alarm below {threshold:g} %)" if threshold is not None else ""
    if pct is not None and threshold is not None and pct >= threshold:
        # back over the threshold, not yet past the margin that ends the alarm
        below = f" (alarm below {threshold:g} %, kept until {threshold + HYSTERESIS_PCT:g} %)"
    return f"battery low{reading}{below}"


#: How far above its threshold a battery must come back for its alarm to end (the watch's
#: ``server.domain.watch.BATTERY_HYSTERESIS_PCT``, said in the alarm's words).
HYSTERESIS_PCT = 2.0
