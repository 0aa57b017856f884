"""Live events as readable lines (``fleetctl watch``). Pure: text in, text out.

A line is ``TIME TOPIC WHAT``: ``TIME`` the server's time of the event (UTC, to the
second), or ``current`` for the state a subscription starts with. Most events are a
line; one that lists things is a line per thing: the ``fleet`` topic's state a line per
vehicle, a vehicle's commands a line per command, its event log a line per entry.

The lines hold what vehicles and people wrote as they wrote it (free-form data as
compact JSON); printing them escapes what a terminal would obey
(``remote_client.output.shown``).
"""

from __future__ import annotations

import json
import math
from typing import Any

from remote_client.sdk import shown_status

__all__ = ["alarms_text", "event_lines", "position_text"]

#: Longest rendering of data the other lines do not know (a unit's own topics).
MAX_DATA_CHARS = 160


def event_lines(push: dict[str, Any]) -> list[str]:
    """The lines an ``event`` push reads as."""
    when = "current" if push.get("snapshot") else _clock(push.get("ts"))
    topic = str(push.get("topic", "?"))
    data = push.get("data")
    parts = topic.split("/")
    if topic == "fleet" and isinstance(data, dict):
        return [f"{when} fleet {_vehicle(v)}" for v in data.get("vehicles", [])] or [
            f"{when} fleet no vehicles"
        ]
    if len(parts) == 3 and parts[0] == "vehicle" and parts[2] in _KINDS:
        head = f"{when} {parts[1]} {parts[2]}"
        if data is None:
            return [f"{head} nothing yet"]
        return [f"{head} {text}" for text in _KINDS[parts[2]](data)]
    return [f"{when} {topic} {_compact(data)}"]


def position_text(pos: dict[str, Any] | None) -> str:
    if not pos or "lat" not in pos:
        return "-"
    return f"{pos['lat']:.5f},{pos['lon']:.5f}"


def alarms_text(view: dict[str, Any]) -> str:
    """A vehicle's alarms (``VehicleView.alarms``) in a line, each with since when (UTC,
    to the second) when the server knows it: ``inside no-go zone pier 3 since 10:02:11Z;
    battery low: 15 % since 10:04:00Z``; empty when it has none."""
    said = (
        str(a.get("message") or a.get("kind"))
        + (f" since {_clock(a['since'])}" if a.get("since") else "")
        for a in view.get("alarms") or []
    )
    return "; ".join(said)


def _clock(ts: Any) -> str:
    """``2026-11-22T10:00:01.123Z`` → ``10:00:01Z``."""
    if isinstance(ts, str) and len(ts) >= 19 and ts[10] == "T":
        return ts[11:19] + "Z"
    return "-"


def _vehicle(v: dict[str, Any]) -> str:
    holder = (v.get("control") or {}).get("holder", "-")
    alarms = alarms_text(v)
    return (
        f"{v.get('vehicle_id')} {v.get('presence')} {position_text(v.get('position'))} "
        f"control={holder}" + (f" ALARM {alarms}" if alarms else "")
    )


def _telemetry(sample: dict[str, Any]) -> list[str]:
    words = [f"#{sample.get('seq')}", position_text(sample)]
    for key, fmt in (
        ("speed_mps", "{:.1f} m/s"),
        ("heading_deg", "{:.0f}°"),
        ("depth_m", "{:.1f} m deep"),
        ("battery_pct", "{:.0f}% battery"),
    ):
        value = sample.get(key)
        if isinstance(value, int | float):
            if key == "battery_pct" and math.isfinite(value):
                # whole percent, down, as the console shows it: 99.96 is not a full battery
                value = math.floor(value)
            words.append(fmt.format(value))
    if sample.get("data"):
        words.append(f"data={_compact(sample['data'])}")
    if sample.get("replayed"):
        words.append("(replayed)")
    return [" ".join(words)]


def _commands(data: dict[str, Any]) -> list[str]:
    commands = data.get("commands") or []
    if not commands:
        return ["no commands"]
    out = []
    for c in commands:
        detail = c.get("detail")
        if detail is None:
            detail = next(
                (h.get("detail") for h in reversed(c.get("history") or []) if h.get("detail")),
                None,
            )
        shown = shown_status({**c, "history": [{"detail": detail}]})
        progress = c.get("progress")
        words = [str(c.get("type")), shown]
        if isinstance(progress, int | float) and shown in ("executing", "accepted"):
            words.append(f"{progress:.0%}")
        if detail and shown != "superseded":
            words.append(f"({detail})")
        words.append(str(c.get("command_id")))
        out.append(" ".join(words))
    return out


def _control(data: dict[str, Any]) -> list[str]:
    control = data.get("control")
    if not control:
        return [f"free (instance {data.get('instance_id')})"]
    return [
        f"held by {control.get('holder')} until {control.get('expires_at')} "
        f"(granted by {control.get('granted_by')}; instance {data.get('instance_id')})"
    ]


def _events(data: dict[str, Any]) -> list[str]:
    events = data.get("events") or []
    return [event_text(e) for e in events] or ["no events"]


def event_text(event: dict[str, Any]) -> str:
    """One entry of the event log: ``kind by actor: data``."""
    words = [str(event.get("kind"))]
    if event.get("actor"):
        words.append(f"by {event['actor']}")
    data = event.get("data")
    if data:
        if event.get("kind") == "command" and isinstance(data, dict) and "status" in data:
            detail = data.get("detail")
            shown = shown_status({**data, "history": [{"detail": detail}]})
            words.append(f"{data.get('type')} {shown} {data.get('command_id')}")
        else:
            words.append(_compact(data))
    return " ".join(words)


def _compact(data: Any) -> str:
    """Free-form data on one line: compact JSON (line breaks and other control
    characters escaped by it)."""
    text = json.dumps(data, separators=(",", ":"), ensure_ascii=False)
    return text if len(text) <= MAX_DATA_CHARS else text[: MAX_DATA_CHARS - 1] + "…"


_KINDS = {
    "telemetry": _telemetry,
    "commands": _commands,
    "control": _control,
    "events": _events,
}
