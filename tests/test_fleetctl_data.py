"""``fleetctl params``, ``events``, ``export``, ``track`` and ``sync`` against a real server:
relative times, every track format, the progress bar, the local copy kept incrementally."""

from __future__ import annotations

import csv
import io
import json
import sqlite3
import xml.etree.ElementTree as ET
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import httpx
import pytest
from PIL import Image
from rich.console import Console

from remote_client import cli_data
from remote_client.tracks import GPX_NS
from server.settings import Settings
from tests.factories import ADMIN_TOKEN, make_vehicle, sample, start_instance
from tests.fleetctl_run import fleetctl
from tests.live import serve

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


async def _vehicle_with_samples(
    c: httpx.AsyncClient, n: int, every_s: float = 1.0, **params: Any
) -> tuple[str, str, dict[str, str], datetime]:
    """A vehicle named ``Osprey`` whose ``n`` samples end now, one every ``every_s``."""
    vid, vh = await make_vehicle(c)
    iid = (await start_instance(c, vid, vh, params=params or None))["instance_id"]
    r = await c.post("/upper/start_instance", headers=vh,
                     json={"vehicle_id": vid, "name": "Osprey", "vehicle_type": "usv"})  # fmt: skip
    assert r.status_code == 200 and r.json()["instance_id"] == iid
    first = datetime.now(UTC) - timedelta(seconds=n * every_s)
    for start in range(0, n, 5000):
        samples = [
            sample(s + 1, first + timedelta(seconds=s * every_s), lat=43.9 + s * 1e-5,
                   depth_m=1.0, speed_mps=1.2)
            for s in range(start, min(n, start + 5000))
        ]  # fmt: skip
        body = {"instance_id": iid, "samples": samples}
        assert (await c.post("/upper/update_param", headers=vh, json=body)).is_success
    return vid, iid, vh, first


def _within(
    points: list[dict[str, Any]],
    every: list[dict[str, Any]],
    read: tuple[datetime, datetime],
    since: float,
    until: float = 0,
) -> None:
    """``points`` are those of ``every`` in the window ``[now - since, now - until)``, for a
    ``now`` read between ``read[0]`` and ``read[1]``: none outside its widest reading, none
    of its narrowest reading missing."""
    before, after = read

    def seqs(low: datetime, high: datetime) -> set[int]:
        return {p["seq"] for p in every if low <= datetime.fromisoformat(p["ts"]) < high}

    got = {p["seq"] for p in points}
    narrowest = seqs(after - timedelta(seconds=since), before - timedelta(seconds=until))
    assert narrowest and narrowest <= got
    assert got <= seqs(before - timedelta(seconds=since), after - timedelta(seconds=until))


async def test_track_in_every_format_over_a_relative_window(
    make_settings: Callable[..., Settings], tmp_path: Path
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, _, _, _ = await _vehicle_with_samples(c, 1200)  # 20 minutes, one a second

        whole = await fleetctl(base, ADMIN_TOKEN, "track", "Osprey", "--since", "1h")
        assert whole.exit_code == 0, whole.output
        track = json.loads(whole.stdout)
        assert len(track["points"]) == 1200 and track["truncated"] is False
        # The last ten minutes of twenty; then 20 to 15 minutes ago. "Now" is read by
        # fleetctl somewhere between ``before`` and ``after``.
        before = datetime.now(UTC)
        recent = await fleetctl(base, ADMIN_TOKEN, "track", "Osprey", "--since", "10m")
        read = (before, datetime.now(UTC))
        _within(json.loads(recent.stdout)["points"], track["points"], read, since=600)
        before = datetime.now(UTC)
        older = await fleetctl(
            base, ADMIN_TOKEN, "track", vid, "--since", "1h", "--until", "15m", "--format", "json"
        )
        read = (before, datetime.now(UTC))
        _within(json.loads(older.stdout)["points"], track["points"], read, 3600, until=900)

        gpx = tmp_path / "osprey.gpx"
        written = await fleetctl(
            base, ADMIN_TOKEN, "track", "Osprey", "--since", "1h", "-o", str(gpx)
        )
        assert written.exit_code == 0 and f"1200 points of {vid} written" in written.stderr
        trkpts = ET.parse(gpx).getroot().findall(f".//{{{GPX_NS}}}trkpt")
        assert len(trkpts) == 1200 and trkpts[0].find(f"{{{GPX_NS}}}ele") is not None

        geojson = tmp_path / "osprey.geojson"
        await fleetctl(base, ADMIN_TOKEN, "track", "Osprey", "--since", "1h", "-o", str(geojson))
        feature = json.loads(geojson.read_text())
        coords = feature["geometry"]["coordinates"]
        assert len(coords) == 1200 and coords[0] == [15.44, 43.9]  # [lon, lat]

        table = tmp_path / "osprey.txt"  # the ending names no format: --format does
        args = ("track", "Osprey", "--since", "1h", "--format", "csv", "-o", str(table))
        assert (await fleetctl(base, ADMIN_TOKEN, *args)).exit_code == 0
        rows = list(csv.DictReader(table.open()))
        assert len(rows) == 1200 and rows[0]["seq"] == "1" and rows[0]["depth_m"] == "1.0"

        png = tmp_path / "osprey.png"
        plotted = await fleetctl(
            base, ADMIN_TOKEN, "track", "Osprey", "--since", "1h", "-o", str(png)
        )
        assert plotted.exit_code == 0, plotted.output
        with Image.open(png) as image:
            assert image.format == "PNG" and image.size == (800, 800)
        few = await fleetctl(
            base, ADMIN_TOKEN, "track", "Osprey", "--since", "1h", "--max-points", "20"
        )
        assert len(json.loads(few.stdout)["points"]) == 20

        empty = await fleetctl(
            base, ADMIN_TOKEN, "track", "Osprey", "--since", "1m", "--until", "2m"
        )
        assert empty.exit_code == 2 and "window is empty" in empty.stderr
        garbled = await fleetctl(base, ADMIN_TOKEN, "track", "Osprey", "--since", "ten minutes")
        assert garbled.exit_code == 2 and "not a time" in garbled.stderr
        to_terminal = await fleetctl(base, ADMIN_TOKEN, "track", "Osprey", "--format", "png")
        assert to_terminal.exit_code == 2 and "-o FILE.png" in to_terminal.stderr
        wrong = await fleetctl(base, ADMIN_TOKEN, "track", "Osprey", "--format", "kml")
        assert wrong.exit_code == 2 and "json, geojson, gpx, csv, png" in wrong.stderr
        unknown = await fleetctl(base, ADMIN_TOKEN, "track", "Zulu")
        assert unknown.exit_code == 1 and "'Zulu'" in unknown.stderr


async def test_a_long_track_comes_page_by_page_with_a_progress_bar(
    make_settings: Callable[..., Settings], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    bar = io.StringIO()
    terminal = Console(file=bar, force_terminal=True, width=100)
    monkeypatch.setattr(cli_data, "errors", terminal)
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        # 12,000 points in the last 100 minutes: two of the server's pages (10,000 each)
        await _vehicle_with_samples(c, 12_000, every_s=0.5)
        out = tmp_path / "long.csv"
        args = ("track", "Osprey", "--since", "2h", "-o", str(out))
        written = await fleetctl(base, ADMIN_TOKEN, *args)
        assert written.exit_code == 0, written.output
    rows = list(csv.DictReader(out.open()))
    assert [int(r["seq"]) for r in rows] == list(range(1, 12_001))  # none lost at the cut
    shown = bar.getvalue()
    assert "track" in shown and "100%" in shown and "12000 points" in shown
    assert "12000 points of" in shown  # the closing line, on the same (error) console


async def test_sync_keeps_a_local_copy_and_a_second_run_fetches_only_what_is_new(
    make_settings: Callable[..., Settings], tmp_path: Path
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, iid, vh, _ = await _vehicle_with_samples(c, 40)
        other, oh = await make_vehicle(c)
        oiid = (await start_instance(c, other, oh))["instance_id"]
        body = {"instance_id": oiid, "samples": [sample(s) for s in range(1, 6)]}
        assert (await c.post("/upper/update_param", headers=oh, json=body)).is_success
        db = tmp_path / "fleet.sqlite"

        first = await fleetctl(base, ADMIN_TOKEN, "sync", "Osprey", other, "--db", str(db))
        assert first.exit_code == 0, first.output
        assert first.stdout.splitlines() == [
            f"{vid}: 40 new samples; 40 in {db} (through seq 40)",
            f"{other}: 5 new samples; 5 in {db} (through seq 5)",
        ]
        later = datetime.now(UTC)
        body = {"instance_id": iid, "samples": [sample(s, later) for s in range(41, 48)]}
        assert (await c.post("/upper/update_param", headers=vh, json=body)).is_success
        second = await fleetctl(
            base, ADMIN_TOKEN, "sync", "Osprey", other, "--db", str(db), "--json"
        )
        assert second.exit_code == 0, second.output
        report = {v["vehicle_id"]: v for v in json.loads(second.stdout)["vehicles"]}
        assert (report[vid]["added"], report[vid]["total"], report[vid]["through_seq"]) == (
            7,
            47,
            47,
        )
        assert report[other]["added"] == 0

        full = await fleetctl(base, ADMIN_TOKEN, "sync", vid, "--db", str(db), "--full")
        assert full.stdout.startswith(f"{vid}: 0 new samples; 47 in")

        unknown = await fleetctl(base, ADMIN_TOKEN, "sync", "Zulu", "--db", str(db))
        assert unknown.exit_code == 1 and "'Zulu'" in unknown.stderr

    with sqlite3.connect(db) as copy:  # offline: the server is gone
        counts = dict(copy.execute("SELECT vehicle_id, count(*) FROM samples GROUP BY 1"))
        assert counts == {vid: 47, other: 5}
        seqs = [s for (s,) in copy.execute("SELECT seq FROM samples WHERE vehicle_id = ?", (vid,))]
        assert sorted(seqs) == list(range(1, 48))
        names = dict(copy.execute("SELECT vehicle_id, name FROM vehicles"))
        assert names[vid] == "Osprey"
        row = copy.execute(
            "SELECT lat, depth_m, speed_mps FROM samples WHERE vehicle_id = ? AND seq = 2", (vid,)
        ).fetchone()
        assert row == (43.90001, 1.0, 1.2)


async def test_params_events_and_export_with_names_and_relative_times(
    make_settings: Callable[..., Settings], tmp_path: Path
) -> None:
    # The vehicle stays online throughout: a presence event between two pages of the log
    # (the test's calls take more than the default 3 s under load) would move the pages.
    quiet = make_settings(stale_after_s=600, offline_after_s=1200)
    async with serve(quiet) as base, httpx.AsyncClient(base_url=base) as c:
        vid, iid, _, _ = await _vehicle_with_samples(c, 600, mode="survey", gain=0.5)

        table = await fleetctl(base, ADMIN_TOKEN, "params", "Osprey")
        assert table.exit_code == 0, table.output
        assert "mode" in table.stdout and '"survey"' in table.stdout and "gain" in table.stdout
        assert f"instance {iid}" in table.stdout
        only = await fleetctl(base, ADMIN_TOKEN, "params", "Osprey", "mode", "--json")
        answer = json.loads(only.stdout)
        assert answer["params"] == {"mode": "survey"} and answer["position"]["seq"] == 600
        typo = await fleetctl(base, ADMIN_TOKEN, "params", "Osprey", "mode", "gian")
        assert typo.exit_code == 0 and '"survey"' in typo.stdout, typo.output
        assert "not reported by Osprey: gian" in typo.stderr  # not an empty row, quietly

        assert (await fleetctl(base, ADMIN_TOKEN, "stop", "Osprey")).exit_code == 0
        log = await fleetctl(base, ADMIN_TOKEN, "events", "Osprey", "--since", "10m")
        assert log.exit_code == 0, log.output
        assert any(
            f"{vid} command by admin stop queued" in line for line in log.stdout.splitlines()
        )
        kinds = await fleetctl(base, ADMIN_TOKEN, "events", "--kind", "command", "--json")
        assert {e["kind"] for e in json.loads(kinds.stdout)["events"]} == {"command"}
        future = await fleetctl(base, ADMIN_TOKEN, "events", "Osprey", "--until", "1d")
        assert future.stdout == ""  # nothing a day ago

        # A page at a time: the next page's cursor said on stderr, --all follows them.
        whole = await fleetctl(base, ADMIN_TOKEN, "events", "Osprey")
        lines = whole.stdout.splitlines()
        assert len(lines) >= 3 and whole.stderr == ""
        first = await fleetctl(base, ADMIN_TOKEN, "events", "Osprey", "--limit", "2")
        assert first.stdout.splitlines() == lines[:2]
        cursor = first.stderr.split("--after ")[1].split()[0]
        rest = await fleetctl(base, ADMIN_TOKEN, "events", "Osprey", "--after", cursor)
        assert rest.stdout.splitlines() == lines[2:] and rest.stderr == ""
        every = await fleetctl(base, ADMIN_TOKEN, "events", "Osprey", "--limit", "1", "--all")
        assert every.stdout.splitlines() == lines and every.stderr == ""

        out = tmp_path / "last.jsonl"
        recent = await fleetctl(
            base, ADMIN_TOKEN, "export", "Osprey", "--since", "5m", "-o", str(out)
        )
        assert recent.exit_code == 0, recent.output
        seqs = [json.loads(line)["seq"] for line in out.read_text().splitlines()]
        assert 295 <= len(seqs) <= 301 and seqs[-1] == 600  # the last five minutes of ten
        bad = await fleetctl(base, ADMIN_TOKEN, "export", "Osprey", "--until", "soon")
        assert bad.exit_code == 2 and "not a time" in bad.stderr
