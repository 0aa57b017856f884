"""A track rendered for the wire: JSON points, GeoJSON, GPX 1.1 or CSV. Pure functions."""

from __future__ import annotations

import csv
import io
from decimal import Decimal
from typing import Any
from xml.sax.saxutils import escape

from fleet_protocol import format_ts, track_geometry
from server.services.telemetry_views import TRACK_FIELDS, TrackResult

CSV_COLUMNS = ("ts", *TRACK_FIELDS)
MEDIA_TYPES = {
    "geojson": "application/geo+json",
    "gpx": "application/gpx+xml",
    "csv": "text/csv; charset=utf-8",
}


def json_points(track: TrackResult) -> list[dict[str, Any]]:
    return [{**p, "ts": format_ts(p["ts"])} for p in track.points]


def track_name(vehicle_id: str, name: str) -> str:
    """A track's name as people read it: the vehicle's name (as the fleet shows it) and,
    as two vehicles may share one, its id: ``H2OmniX Alpha (demo-usv-1)``; the id alone
    for a vehicle with no name (or named by its id)."""
    name = name.strip()
    return f"{name} ({vehicle_id})" if name and name != vehicle_id else vehicle_id


def geojson(track: TrackResult, name: str) -> dict[str, Any]:
    """One Feature with a LineString (``[lon, lat]``); its ``name`` (:func:`track_name`),
    times and paging in its properties. A LineString has two positions at least (RFC
    7946): one point is a Point, none a null geometry, so every answer is valid GeoJSON."""
    return {
        "type": "Feature",
        "geometry": track_geometry([[p["lon"], p["lat"]] for p in track.points]),
        "properties": {
            "name": name,
            "vehicle_id": track.vehicle_id,
            "times": [format_ts(p["ts"]) for p in track.points],
            "seqs": [p["seq"] for p in track.points],
            "truncated": track.truncated,
            "next_from": format_ts(track.next_from) if track.next_from else None,
        },
    }


def gpx(track: TrackResult, name: str, gap_s: float | None = None) -> str:
    """GPX 1.1: one ``trk`` named ``name`` (:func:`track_name`), a ``trkseg`` for each run
    of points no more than ``gap_s`` apart (a vehicle out of contact longer than that, or
    not recording, starts a new one: no straight line is drawn across the gap); depth as
    negative elevation."""
    out = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        '<gpx version="1.1" creator="fleet-cloud" xmlns="http://www.topografix.com/GPX/1/1">',
        f"<trk><name>{escape(name)}</name><trkseg>",
    ]
    last = None
    for p in track.points:
        if gap_s is not None and last is not None and (p["ts"] - last).total_seconds() > gap_s:
            out.append("</trkseg><trkseg>")
        last = p["ts"]
        ele = f"<ele>{_decimal(-p['depth_m'])}</ele>" if "depth_m" in p else ""
        out.append(
            f'<trkpt lat="{_decimal(p["lat"])}" lon="{_decimal(p["lon"])}">'
            f"{ele}<time>{format_ts(p['ts'])}</time></trkpt>"
        )
    out.append("</trkseg></trk></gpx>")
    return "\n".join(out) + "\n"


def _decimal(value: float) -> str:
    """A float as GPX's ``xsd:decimal`` writes it: the shortest text that reads back as
    the same float, without an exponent (``5e-05`` is ``0.00005``)."""
    text = repr(float(value))
    return text if "e" not in text else format(Decimal(text), "f")


def csv_text(track: TrackResult) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for p in track.points:
        writer.writerow([format_ts(p["ts"]), *(p.get(name, "") for name in TRACK_FIELDS)])
    return buf.getvalue()


def paging_headers(track: TrackResult) -> dict[str, str]:
    """For the formats without a place for them: whether the track was cut, and where."""
    headers = {"X-Track-Truncated": "true" if track.truncated else "false"}
    if track.next_from is not None:
        headers["X-Track-Next-From"] = format_ts(track.next_from)
    return headers
