"""The operator tools' pure parts: times as people type them, names, readable event lines,
track pages joined, superseded commands."""

from __future__ import annotations

import csv
import io
import json
import xml.etree.ElementTree as ET
from datetime import UTC, datetime, timedelta
from typing import Any

import httpx
import pytest

from remote_client.lines import event_lines
from remote_client.output import shown
from remote_client.sdk import (
    AmbiguousName,
    FleetApiError,
    FleetClient,
    UnknownVehicle,
    pick_vehicle,
    shown_status,
)
from remote_client.times import BadTime, parse_when, when_text
from remote_client.tracks import GPX_NS, TrackJoiner, plot_png

NOW = datetime(2026, 11, 22, 12, 0, 0, tzinfo=UTC)


@pytest.mark.parametrize(
    ("text", "ago"),
    [
        ("10m", timedelta(minutes=10)),
        ("2h", timedelta(hours=2)),
        ("90s", timedelta(seconds=90)),
        ("1d", timedelta(days=1)),
        ("1w", timedelta(weeks=1)),
        ("1h30m", timedelta(hours=1, minutes=30)),
        ("1.5h", timedelta(hours=1, minutes=30)),
        ("-10m", timedelta(minutes=10)),
        ("10m ago", timedelta(minutes=10)),
        (" 2H ", timedelta(hours=2)),
        ("now", timedelta(0)),
    ],
)
def test_relative_times_count_back_from_now(text: str, ago: timedelta) -> None:
    assert parse_when(text, NOW) == NOW - ago


def test_iso_times_are_taken_as_given_and_naive_ones_as_utc() -> None:
    assert parse_when("2026-11-22T10:00:00Z", NOW) == datetime(2026, 11, 22, 10, tzinfo=UTC)
    assert parse_when("2026-11-22T10:00", NOW) == datetime(2026, 11, 22, 10, tzinfo=UTC)
    assert parse_when("2026-11-22T12:00:00+02:00", NOW) == datetime(2026, 11, 22, 10, tzinfo=UTC)
    assert parse_when("2026-11-22", NOW) == datetime(2026, 11, 22, tzinfo=UTC)
    assert when_text("10m", NOW) == "2026-11-22T11:50:00.000Z"  # the wire's format
    assert when_text(None, NOW) is None
    for bad in ("10 parsecs", "m10", "yesterday-ish", ""):
        with pytest.raises(BadTime, match="not a time"):
            parse_when(bad, NOW)


@pytest.mark.parametrize(
    "text",
    ["0001-01-01T00:00:00+01:00", "9999-12-31T23:59:59-05:00", "100000000d", "99999999999w"],
)
def test_a_time_past_what_a_clock_can_hold_is_a_bad_time_not_a_crash(text: str) -> None:
    with pytest.raises(BadTime, match="not a time"):
        parse_when(text, NOW)


FLEET: list[dict[str, Any]] = [
    {"vehicle_id": "usv-1", "name": "Alpha", "instance_id": "i-1"},
    {"vehicle_id": "usv-2", "name": "Bravo", "instance_id": "i-2"},
    {"vehicle_id": "usv-3", "name": "bravo", "instance_id": None},
    {"vehicle_id": "alpha", "name": "Charlie", "instance_id": "i-3"},
]


def test_a_name_picks_its_vehicle_an_id_first_then_the_exact_name_then_any_case() -> None:
    assert pick_vehicle("usv-2", FLEET)["vehicle_id"] == "usv-2"
    assert pick_vehicle("alpha", FLEET)["vehicle_id"] == "alpha"  # an id before a name
    assert pick_vehicle("Alpha", FLEET)["vehicle_id"] == "usv-1"
    assert pick_vehicle("Bravo", FLEET)["vehicle_id"] == "usv-2"  # exact before any case
    assert pick_vehicle("CHARLIE", FLEET)["vehicle_id"] == "alpha"
    with pytest.raises(AmbiguousName) as two:
        pick_vehicle("BRAVO", FLEET)
    assert "usv-2, usv-3" in two.value.message and two.value.code == "ambiguous_name"
    with pytest.raises(UnknownVehicle) as none:
        pick_vehicle("Delta", FLEET)
    assert none.value.status == 404 and "'Delta'" in none.value.message


def test_a_command_a_stop_cancelled_shows_as_superseded() -> None:
    superseded = {
        "status": "cancelled",
        "history": [{"detail": None}, {"detail": "superseded_by_stop"}],
    }
    assert shown_status(superseded) == "superseded"
    replaced = {"status": "cancelled", "history": [{"detail": "superseded_by go_to c-2"}]}
    assert shown_status(replaced) == "superseded"
    cancelled = {"status": "cancelled", "history": [{"detail": "lease_ended"}]}
    assert shown_status(cancelled) == "cancelled"
    assert shown_status({"status": "done", "history": []}) == "done"


def test_events_read_as_one_line_each() -> None:
    sample = {
        "op": "event",
        "topic": "vehicle/usv-1/telemetry",
        "ts": "2026-11-22T10:00:01.123Z",
        "data": {"seq": 7, "lat": 43.94, "lon": 15.44, "speed_mps": 1.52, "heading_deg": 90.0,
                 "battery_pct": 88.4, "replayed": True},
    }  # fmt: skip
    assert event_lines(sample) == [
        "10:00:01Z usv-1 telemetry #7 43.94000,15.44000 1.5 m/s 90° 88% battery (replayed)"
    ]
    nearly_full = {**sample, "data": {**sample["data"], "battery_pct": 99.96}}
    assert "99% battery" in event_lines(nearly_full)[0]  # down, as the console: not full
    moved = {
        "op": "event",
        "topic": "vehicle/usv-1/commands",
        "ts": "2026-11-22T10:00:02.000Z",
        "data": {"commands": [{"command_id": "c-1", "type": "go_to", "status": "cancelled",
                               "detail": "superseded_by_stop"}]},
    }  # fmt: skip
    assert event_lines(moved) == ["10:00:02Z usv-1 commands go_to superseded c-1"]
    control = {
        "op": "event",
        "topic": "vehicle/usv-1/control",
        "snapshot": True,
        "data": {"instance_id": "i-1", "control": None},
    }
    assert event_lines(control) == ["current usv-1 control free (instance i-1)"]
    fleet = {
        "op": "event",
        "topic": "fleet",
        "snapshot": True,
        "data": {"vehicles": [
            {"vehicle_id": "usv-1", "presence": "online", "position": {"lat": 1.0, "lon": 2.0},
             "control": {"holder": "ana"}},
            {"vehicle_id": "usv-2", "presence": "offline", "position": None, "control": None},
            {"vehicle_id": "usv-3", "presence": "stale", "position": None, "control": None,
             "alarms": [{"kind": "failsafe", "message": "in failsafe: stop"},
                        {"kind": "no_go_zone", "message": "inside no-go zone \u202eXY"}]},
        ]},
    }  # fmt: skip
    assert [shown(line) for line in event_lines(fleet)] == [
        "current fleet usv-1 online 1.00000,2.00000 control=ana",
        "current fleet usv-2 offline - control=-",
        "current fleet usv-3 stale - control=- ALARM in failsafe: stop; "
        "inside no-go zone \\u202eXY",
    ]
    own = {"op": "event", "topic": "user/w/seg/usv-1", "ts": "2026-11-22T10:00:03Z",
           "data": {"mask": [1, 2]}}  # fmt: skip
    assert event_lines(own) == ['10:00:03Z user/w/seg/usv-1 {"mask":[1,2]}']


def _points(first: int, n: int) -> list[dict[str, object]]:
    return [{"ts": f"2026-11-22T10:00:{s:02d}.000Z", "seq": s, "lat": 43.9 + s * 1e-4,
             "lon": 15.4} for s in range(first, first + n)]  # fmt: skip


def test_track_pages_join_into_one_document_of_their_format() -> None:
    pages = [_points(1, 3), _points(4, 2)]
    joined = TrackJoiner("json")
    for i, points in enumerate(pages):
        joined.add({"vehicle_id": "usv-1", "points": points, "truncated": i == 0,
                    "next_from": "x" if i == 0 else None})  # fmt: skip
    whole = json.loads(joined.text())
    assert [p["seq"] for p in whole["points"]] == [1, 2, 3, 4, 5] and joined.points == 5
    assert whole["truncated"] is False and whole["next_from"] is None

    geo = TrackJoiner("geojson")
    for points in pages:
        geo.add(json.dumps({
            "type": "Feature",
            "geometry": {"type": "LineString",
                         "coordinates": [[p["lon"], p["lat"]] for p in points]},
            "properties": {"times": [p["ts"] for p in points], "seqs": [p["seq"] for p in points],
                           "truncated": True, "next_from": "x"},
        }))  # fmt: skip
    feature = json.loads(geo.text())
    assert len(feature["geometry"]["coordinates"]) == 5
    assert feature["properties"]["seqs"] == [1, 2, 3, 4, 5]
    assert feature["properties"]["truncated"] is False

    lone = TrackJoiner("geojson")  # pages the server wrote with one point each: Points
    for points in (_points(1, 1), _points(2, 1)):
        lone.add(json.dumps({
            "type": "Feature",
            "geometry": {"type": "Point", "coordinates": [points[0]["lon"], points[0]["lat"]]},
            "properties": {"times": [points[0]["ts"]], "seqs": [points[0]["seq"]]},
        }))  # fmt: skip
    geometry = json.loads(lone.text())["geometry"]
    assert geometry["type"] == "LineString" and len(geometry["coordinates"]) == 2

    held = TrackJoiner("geojson")  # one point a page as the server writes it now: held twice
    for points in (_points(1, 1), _points(2, 1), _points(3, 1)):
        at = [points[0]["lon"], points[0]["lat"]]
        held.add(json.dumps({
            "type": "Feature",
            "geometry": {"type": "LineString", "coordinates": [at, at]},
            "properties": {"times": [points[0]["ts"]], "seqs": [points[0]["seq"]]},
        }))  # fmt: skip
    feature = json.loads(held.text())
    assert len(feature["geometry"]["coordinates"]) == 3 and held.points == 3

    table = TrackJoiner("csv")
    for points in pages:
        table.add("ts,seq\n" + "".join(f"{p['ts']},{p['seq']}\n" for p in points))
    rows = list(csv.DictReader(io.StringIO(table.text())))
    assert [r["seq"] for r in rows] == ["1", "2", "3", "4", "5"]  # one header

    gpx = TrackJoiner("gpx")
    for points in pages:
        gpx.add(
            f'<?xml version="1.0" encoding="UTF-8"?>\n<gpx version="1.1" xmlns="{GPX_NS}">'
            "<trk><name>usv-1</name><trkseg>"
            + "".join(f'<trkpt lat="{p["lat"]}" lon="{p["lon"]}"><time>{p["ts"]}</time></trkpt>'
                      for p in points)
            + "</trkseg></trk></gpx>"
        )  # fmt: skip
    tree = ET.fromstring(gpx.text().split("\n", 1)[1])
    assert len(tree.findall(f".//{{{GPX_NS}}}trkpt")) == 5 and gpx.points == 5
    assert len(tree.findall(f".//{{{GPX_NS}}}trkseg")) == 1


def test_a_plot_is_a_png() -> None:
    out = io.BytesIO()
    plot_png(_points(1, 30), "usv-1", out)
    assert out.getvalue().startswith(b"\x89PNG\r\n\x1a\n")
    empty = io.BytesIO()
    plot_png([], "nothing", empty)  # an empty window still plots (and says so)
    assert empty.getvalue().startswith(b"\x89PNG")


async def test_a_refusal_says_when_to_try_again() -> None:
    """A 429 or a 503 carries Retry-After: the SDK's error keeps it for the caller."""

    def busy(request: httpx.Request) -> httpx.Response:
        body = {"error": {"code": "rate_limited", "message": "slow down", "details": None}}
        return httpx.Response(429, json=body, headers={"Retry-After": "7"})

    async with httpx.AsyncClient(
        transport=httpx.MockTransport(busy), base_url="http://fleet.test"
    ) as http:
        with pytest.raises(FleetApiError) as refused:
            await FleetClient("http://fleet.test", "fct_x", client=http).vehicles()
    assert (refused.value.status, refused.value.retry_after_s) == (429, 7.0)
    assert refused.value.details == []


def test_data_that_would_reorder_a_terminal_line_is_shown_escaped() -> None:
    push = {"op": "event", "topic": "user/ana/notes", "ts": "2026-11-22T10:00:00.000Z",
            "data": {"reason": "line1\nline2\u0000\u202e evil"}}  # fmt: skip
    [line] = event_lines(push)
    assert "\n" not in line and "\x00" not in line  # JSON escapes them
    printed = shown(line)
    assert "\u202e" not in printed and "\\u202e evil" in printed


def test_text_is_shown_with_what_a_terminal_obeys_escaped() -> None:
    assert shown("\x1b]0;pwned\x07\x1b[2Jk") == "\\x1b]0;pwned\\x07\\x1b[2Jk"
    assert shown("abc\u202edef\u2066") == "abc\\u202edef\\u2066"
    assert shown("a\nb\tc\x7f\x9b") == "a\\x0ab\\x09c\\x7f\\x9b"
    assert shown("pier 3 — ok [/x] :smile:") == "pier 3 — ok [/x] :smile:"
