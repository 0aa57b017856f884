"""Telemetry through HTTP: ingest answers, track and telemetry views, formats, refusals."""

from __future__ import annotations

import csv
import io
import xml.etree.ElementTree as ET
from datetime import UTC, datetime, timedelta
from typing import Any

import httpx
import pytest

from tests.factories import ADMIN, bearer, make_user, make_vehicle, sample, start_instance, unique

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")

T0 = datetime(2026, 11, 22, 10, 0, 0, tzinfo=UTC)  # sample(n) is at T0 + n s
WINDOW = {"from": "2026-11-22T09:00:00.000Z", "to": "2026-11-22T11:00:00.000Z"}


async def vehicle_with_samples(
    client: httpx.AsyncClient, seqs: range, **extra: Any
) -> tuple[str, dict[str, str], str]:
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    r = await client.post(
        "/upper/update_param",
        headers=vh,
        json={"instance_id": iid, "samples": [sample(n, **extra) for n in seqs]},
    )
    assert r.status_code == 200, r.text
    return vid, vh, iid


async def test_update_param_counts_duplicates_and_reports_marks(client: httpx.AsyncClient) -> None:
    vid, vh, iid = await vehicle_with_samples(client, range(1, 11))
    r = await client.post(
        "/upper/update_param",
        headers=vh,
        json={"instance_id": iid, "samples": [sample(n) for n in range(8, 13)]},
    )
    body = r.json()
    assert (body["accepted"], body["duplicates"], body["acked_through_seq"]) == (2, 3, 12)
    assert body["durable_through_seq"] <= 12
    again = await start_instance(client, vid, vh)
    assert again["last_seq"] == 12


async def test_an_update_with_only_fields_it_does_not_know_is_refused_naming_the_field(
    client: httpx.AsyncClient,
) -> None:
    """``sample`` for ``samples`` was answered 200 "0 accepted": the vehicle took it for
    its samples refused as duplicates, or for stored. Unknown fields beside known ones are
    still ignored (a newer client's), and an empty update is still a contact."""
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    typo = {"instance_id": iid, "sample": [sample(1)]}
    r = await client.post("/upper/update_param", headers=vh, json=typo)
    assert r.status_code == 422, r.text
    error = r.json()["error"]
    assert error["details"][0]["field"] == "sample", error
    assert "did you mean samples" in error["message"], error
    newer = {"instance_id": iid, "samples": [sample(1)], "priority": "high"}
    r = await client.post("/upper/update_param", headers=vh, json=newer)
    assert r.status_code == 200 and r.json()["accepted"] == 1, r.text
    r = await client.post("/upper/update_param", headers=vh, json={"instance_id": iid})
    assert r.status_code == 200 and r.json()["accepted"] == 0, r.text
    for said in ({"samples": []}, {"params": {}}):  # sent, though empty: a newer client's
        newer_empty = {"instance_id": iid, **said, "battery_summary": {}}
        r = await client.post("/upper/update_param", headers=vh, json=newer_empty)
        assert r.status_code == 200 and r.json()["accepted"] == 0, r.text


async def test_track_json(client: httpx.AsyncClient) -> None:
    vid, _, _ = await vehicle_with_samples(client, range(1, 31), speed_mps=1.5)
    r = await client.get(
        f"/api/vehicles/{vid}/track",
        headers=ADMIN,
        params={"from": "2026-11-22T10:00:05.000Z", "to": "2026-11-22T10:00:25.000Z"},
    )
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["vehicle_id"] == vid and body["truncated"] is False
    assert body["next_from"] is None
    assert [p["seq"] for p in body["points"]] == list(range(5, 25))
    first = body["points"][0]
    assert first["ts"] == "2026-11-22T10:00:05.000Z" and first["speed_mps"] == 1.5


async def test_track_default_window_ends_now(clocked_client: httpx.AsyncClient) -> None:
    # The fake clock reads T0: samples after it are outside the default window.
    vid, _, _ = await vehicle_with_samples(clocked_client, range(1, 5))
    r = await clocked_client.get(f"/api/vehicles/{vid}/track", headers=ADMIN)
    assert r.status_code == 200 and r.json()["points"] == []


async def test_track_downsampled(client: httpx.AsyncClient) -> None:
    vid, _, _ = await vehicle_with_samples(client, range(1, 201))
    r = await client.get(
        f"/api/vehicles/{vid}/track", headers=ADMIN, params={**WINDOW, "max_points": 20}
    )
    points = r.json()["points"]
    assert len(points) == 20 and (points[0]["seq"], points[-1]["seq"]) == (1, 200)


async def test_track_geojson(client: httpx.AsyncClient) -> None:
    vid, _, _ = await vehicle_with_samples(client, range(1, 4))
    r = await client.get(
        f"/api/vehicles/{vid}/track", headers=ADMIN, params={**WINDOW, "format": "geojson"}
    )
    assert r.headers["content-type"].startswith("application/geo+json")
    feature = r.json()
    assert feature["type"] == "Feature" and feature["geometry"]["type"] == "LineString"
    assert feature["geometry"]["coordinates"][0] == [15.44, 43.94]  # [lon, lat]
    assert len(feature["properties"]["times"]) == 3


async def test_a_track_of_one_point_or_none_is_still_valid_geojson(
    client: httpx.AsyncClient,
) -> None:
    """Always a Feature with a LineString (the contract's). A LineString has two positions
    at least (RFC 7946): one point is held twice; none is a line with no coordinates."""
    vid, _, _ = await vehicle_with_samples(client, range(1, 2))
    params = {**WINDOW, "format": "geojson"}
    one = (await client.get(f"/api/vehicles/{vid}/track", headers=ADMIN, params=params)).json()
    point = [15.44, 43.94]
    assert one["geometry"] == {"type": "LineString", "coordinates": [point, point]}
    assert one["properties"]["seqs"] == [1]
    empty_id, _ = await make_vehicle(client)
    r = await client.get(f"/api/vehicles/{empty_id}/track", headers=ADMIN, params=params)
    assert r.json()["type"] == "Feature"
    assert r.json()["geometry"] == {"type": "LineString", "coordinates": []}


async def test_track_gpx(client: httpx.AsyncClient) -> None:
    vid, _, _ = await vehicle_with_samples(client, range(1, 4), depth_m=2.5)
    r = await client.get(
        f"/api/vehicles/{vid}/track", headers=ADMIN, params={**WINDOW, "format": "gpx"}
    )
    assert r.headers["content-type"].startswith("application/gpx+xml")
    ns = {"g": "http://www.topografix.com/GPX/1/1"}
    points = ET.fromstring(r.content).findall(".//g:trkpt", ns)
    assert [(p.get("lat"), p.get("lon")) for p in points] == [("43.94", "15.44")] * 3
    assert points[0].findtext("g:time", namespaces=ns) == "2026-11-22T10:00:01.000Z"
    assert points[0].findtext("g:ele", namespaces=ns) == "-2.5"

    # Near the prime meridian, at the surface: decimals, never an exponent (xsd:decimal).
    tiny, _, _ = await vehicle_with_samples(client, range(1, 2), lon=0.00005, depth_m=0.00001)
    r = await client.get(
        f"/api/vehicles/{tiny}/track", headers=ADMIN, params={**WINDOW, "format": "gpx"}
    )
    [point] = ET.fromstring(r.content).findall(".//g:trkpt", ns)
    assert (point.get("lon"), point.findtext("g:ele", namespaces=ns)) == ("0.00005", "-0.00001")
    assert "e-" not in r.text


async def test_a_gpx_track_is_cut_where_the_vehicle_was_out_of_contact(
    client: httpx.AsyncClient,
) -> None:
    """Points farther apart than FLEET_OFFLINE_AFTER_S (10 s) are in two segments: a GPX
    viewer drew a straight line across the two minutes the boat was not heard."""
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    t0 = datetime(2026, 11, 22, 10, 0, 0, tzinfo=UTC)
    times = [t0 + timedelta(seconds=s) for s in (1, 2, 3, 123, 124, 134, 145)]
    body = {"instance_id": iid, "samples": [sample(n, ts=t) for n, t in enumerate(times, 1)]}
    assert (await client.post("/upper/update_param", headers=vh, json=body)).is_success
    r = await client.get(
        f"/api/vehicles/{vid}/track", headers=ADMIN, params={**WINDOW, "format": "gpx"}
    )
    ns = {"g": "http://www.topografix.com/GPX/1/1"}
    segments = ET.fromstring(r.content).findall(".//g:trkseg", ns)
    # 3 s -> 123 s and 134 s -> 145 s are gaps; 124 s -> 134 s (10 s) is not
    assert [len(seg.findall("g:trkpt", ns)) for seg in segments] == [3, 3, 1]


async def test_a_track_is_named_by_its_vehicle_s_name_and_id(client: httpx.AsyncClient) -> None:
    """A GPX track and a GeoJSON Feature were named by the vehicle's id alone: they carry
    its name as the fleet shows it (the one its start announced, else the registered one)
    and, as two vehicles may share one, its id; the id alone without a name."""
    ns = {"g": "http://www.topografix.com/GPX/1/1"}
    names = {}
    for name, announced in (("Lady <Ann> & Co", ""), ("", ""), ("Registered", "At sea")):
        vid = unique("usv")
        body = {"vehicle_id": vid, "name": name, "vehicle_type": "usv"}
        vh = bearer((await client.post("/api/vehicles", headers=ADMIN, json=body)).json()["token"])
        iid = (await start_instance(client, vid, vh, name=announced))["instance_id"]
        samples = {"instance_id": iid, "samples": [sample(n) for n in range(1, 3)]}
        assert (await client.post("/upper/update_param", headers=vh, json=samples)).is_success
        url = f"/api/vehicles/{vid}/track"
        gpx = await client.get(url, headers=ADMIN, params={**WINDOW, "format": "gpx"})
        feature = await client.get(url, headers=ADMIN, params={**WINDOW, "format": "geojson"})
        names[name] = (
            vid,
            ET.fromstring(gpx.content).findtext("g:trk/g:name", namespaces=ns),
            feature.json()["properties"]["name"],
            feature.json()["properties"]["vehicle_id"],
        )
    vid, in_gpx, in_geojson, feature_id = names["Lady <Ann> & Co"]
    assert in_gpx == in_geojson == f"Lady <Ann> & Co ({vid})" and feature_id == vid
    vid, in_gpx, in_geojson, _ = names[""]
    assert in_gpx == in_geojson == vid
    vid, in_gpx, in_geojson, _ = names["Registered"]
    assert in_gpx == in_geojson == f"At sea ({vid})"  # as the console and fleetctl show it


async def test_track_csv(client: httpx.AsyncClient) -> None:
    vid, _, _ = await vehicle_with_samples(client, range(1, 4))
    r = await client.get(
        f"/api/vehicles/{vid}/track", headers=ADMIN, params={**WINDOW, "format": "csv"}
    )
    assert r.headers["content-type"].startswith("text/csv")
    assert r.headers["x-track-truncated"] == "false"
    rows = list(csv.DictReader(io.StringIO(r.text)))
    assert [row["seq"] for row in rows] == ["1", "2", "3"]
    assert rows[0]["ts"] == "2026-11-22T10:00:01.000Z" and rows[0]["lat"] == "43.94"


async def test_track_is_cut_at_10000_points_with_next_from(client: httpx.AsyncClient) -> None:
    vid, vh, iid = await vehicle_with_samples(client, range(1, 5001))  # at most 5000 a call
    for chunk in (range(5001, 10001), range(10001, 10006)):
        r = await client.post(
            "/upper/update_param",
            headers=vh,
            json={"instance_id": iid, "samples": [sample(n) for n in chunk]},
        )
        assert r.json()["accepted"] == len(chunk)
    day = {"from": "2026-11-22T00:00:00.000Z", "to": "2026-11-23T00:00:00.000Z"}
    r = await client.get(f"/api/vehicles/{vid}/track", headers=ADMIN, params=day)
    body = r.json()
    assert len(body["points"]) == 10_000 and body["truncated"] is True
    assert body["next_from"] == _ts(10_001)
    rest = await client.get(
        f"/api/vehicles/{vid}/track",
        headers=ADMIN,
        params={"from": body["next_from"], "to": "2026-11-23T00:00:00.000Z"},
    )
    assert [p["seq"] for p in rest.json()["points"]] == list(range(10_001, 10_006))


def _ts(seq: int) -> str:
    return (T0 + timedelta(seconds=seq)).strftime("%Y-%m-%dT%H:%M:%S.000Z")


async def test_telemetry_pages_by_seq(client: httpx.AsyncClient) -> None:
    vid, _, _ = await vehicle_with_samples(client, range(1, 26), battery_pct=80, data={"rpm": 900})
    url = f"/api/vehicles/{vid}/telemetry"
    first = (await client.get(url, headers=ADMIN, params={"limit": 10})).json()
    assert [s["seq"] for s in first["samples"]] == list(range(1, 11))
    assert first["next_after_seq"] == 10
    assert first["samples"][0]["data"] == {"rpm": 900}
    assert first["samples"][0]["ts"] == "2026-11-22T10:00:01.000Z"
    rest = (await client.get(url, headers=ADMIN, params={"after_seq": 20, "limit": 10})).json()
    assert [s["seq"] for s in rest["samples"]] == list(range(21, 26))
    assert rest["next_after_seq"] is None
    window = (await client.get(url, headers=ADMIN, params={"from": _ts(3), "to": _ts(6)})).json()
    assert [s["seq"] for s in window["samples"]] == [3, 4, 5]


async def test_bad_query_values_are_422_naming_the_field(client: httpx.AsyncClient) -> None:
    vid, _, _ = await vehicle_with_samples(client, range(1, 3))
    cases = [
        ("track", {"from": "yesterday"}, "from"),
        ("track", {"to": "2026-13-01T00:00:00Z"}, "to"),
        ("track", {"max_points": "1"}, "max_points"),
        ("track", {"max_points": "10001"}, "max_points"),
        ("track", {"max_points": "many"}, "max_points"),
        ("track", {"format": "kml"}, "format"),
        ("track", {"from": _ts(10), "to": _ts(5)}, "from"),
        ("telemetry", {"limit": "0"}, "limit"),
        ("telemetry", {"limit": "10001"}, "limit"),
        ("telemetry", {"after_seq": "-2"}, "after_seq"),
        ("telemetry", {"after_seq": "x"}, "after_seq"),
        ("telemetry", {"from": _ts(10), "to": _ts(10)}, "from"),
    ]
    for view, params, field in cases:
        r = await client.get(f"/api/vehicles/{vid}/{view}", headers=ADMIN, params=params)
        assert r.status_code == 422, (view, params, r.text)
        error = r.json()["error"]
        assert error["code"] == "invalid"
        assert field in [d["field"] for d in error["details"]], (view, params, error)


async def test_unknown_vehicle_is_404(client: httpx.AsyncClient) -> None:
    for view in ("track", "telemetry"):
        r = await client.get(f"/api/vehicles/no-such-usv/{view}", headers=ADMIN)
        assert r.status_code == 404 and r.json()["error"]["code"] == "not_found"


async def test_who_may_read(client: httpx.AsyncClient) -> None:
    vid, vh, _ = await vehicle_with_samples(client, range(1, 3))
    _, allowed = await make_user(client, "viewer", vehicles=[vid])
    _, other = await make_user(client, "operator", vehicles=[])
    for view in ("track", "telemetry"):
        url = f"/api/vehicles/{vid}/{view}"
        assert (await client.get(url, headers=allowed)).status_code == 200
        assert (await client.get(url, headers=other)).status_code == 404  # as if none
        assert (await client.get(url, headers=vh)).status_code == 403  # a vehicle token
        assert (await client.get(url)).status_code == 401


async def test_every_time_a_sample_may_have_is_in_the_widest_window(
    client: httpx.AsyncClient,
) -> None:
    """A sample's ``ts`` lies from 1970 to before 2100, the widest window from 1970 to 2100
    (``to`` excluded): the first and last times a sample may have are both in it; 2100
    itself is refused as a sample's time and taken as a window's ``to``."""
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    first, last = datetime(1970, 1, 1, tzinfo=UTC), datetime(2099, 12, 31, 23, 59, 59, 999000, UTC)
    r = await client.post(
        "/upper/update_param",
        headers=vh,
        json={"instance_id": iid, "samples": [sample(1, ts=first), sample(2, ts=last)]},
    )
    assert r.status_code == 200 and r.json()["accepted"] == 2, r.text
    r = await client.post(
        "/upper/update_param",
        headers=vh,
        json={"instance_id": iid, "samples": [{**sample(3), "ts": "2100-01-01T00:00:00Z"}]},
    )
    assert r.status_code == 422, r.text
    assert [d["field"] for d in r.json()["error"]["details"]] == ["samples.0.ts"]
    widest = {"from": "1970-01-01T00:00:00Z", "to": "2100-01-01T00:00:00Z"}
    r = await client.get(f"/api/vehicles/{vid}/track", headers=ADMIN, params=widest)
    assert r.status_code == 200, r.text
    assert [(p["seq"], p["ts"]) for p in r.json()["points"]] == [
        (1, "1970-01-01T00:00:00.000Z"),
        (2, "2099-12-31T23:59:59.999Z"),
    ]
    r = await client.get("/api/events", headers=ADMIN, params=widest)
    assert r.status_code == 200, r.text
    for route in (f"/api/vehicles/{vid}/track", f"/api/vehicles/{vid}/telemetry", "/api/events"):
        r = await client.get(route, headers=ADMIN, params={"to": "2100-01-01T00:00:00.001Z"})
        assert r.status_code == 422, (route, r.text)
        assert [d["field"] for d in r.json()["error"]["details"]] == ["to"], route
