"""``fleetctl export`` against a real server: every sample page by page, as JSON lines or
CSV to a file (the format by --format or the file's ending), and a quiet end when its
output is closed (``| head -1``)."""

from __future__ import annotations

import asyncio
import csv
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from server.settings import Settings
from tests.factories import ADMIN_TOKEN, sample
from tests.fleetctl_run import fleetctl, served_vehicle

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


async def test_export_writes_every_sample_page_by_page(
    make_settings: Callable[..., Settings], tmp_path: Path
) -> None:
    async with served_vehicle(make_settings()) as (base, c, vid, vh, iid):
        samples = [sample(seq, depth_m=1.5) for seq in range(1, 26)]
        samples[3]["data"] = {"sonar": "ok"}
        body = {"instance_id": iid, "samples": samples}
        assert (await c.post("/upper/update_param", headers=vh, json=body)).is_success

        lines = await fleetctl(base, ADMIN_TOKEN, "export", vid, "--page", "10")
        assert lines.exit_code == 0, lines.output
        rows = [json.loads(line) for line in lines.stdout.splitlines()]
        assert [r["seq"] for r in rows] == list(range(1, 26))  # three pages, none twice
        assert rows[3]["data"] == {"sonar": "ok"} and rows[0]["depth_m"] == 1.5

        target = tmp_path / "track.csv"
        written = await fleetctl(
            base, ADMIN_TOKEN, "export", vid, "--format", "csv", "-o", str(target), "--page", "7"
        )
        assert written.exit_code == 0 and "25 samples written" in written.stderr
        table = list(csv.DictReader(target.open()))
        assert [int(r["seq"]) for r in table] == list(range(1, 26))
        assert json.loads(table[3]["data"]) == {"sonar": "ok"} and table[0]["data"] == ""
        assert float(table[0]["depth_m"]) == 1.5
        by_ending = tmp_path / "again.CSV"  # no --format: the file's ending chooses csv
        again = await fleetctl(base, ADMIN_TOKEN, "export", vid, "-o", str(by_ending))
        assert again.exit_code == 0, again.output
        assert by_ending.read_text() == target.read_text()

        unknown = await fleetctl(base, ADMIN_TOKEN, "export", "no-such-vehicle")
        assert unknown.exit_code == 1 and "404" in unknown.stderr
        wrong = await fleetctl(base, ADMIN_TOKEN, "export", vid, "--format", "xml")
        assert wrong.exit_code == 2 and "jsonl, csv" in wrong.stderr


async def test_export_stops_quietly_when_its_output_is_closed(
    make_settings: Callable[..., Settings],
) -> None:
    """``fleetctl export ... | head -1`` on more samples than a pipe holds: exit 141, quiet."""
    async with served_vehicle(make_settings()) as (base, c, vid, vh, iid):
        for first_seq in range(1, 2001, 200):  # ~300 kB of JSON lines, a pipe holds 64 kB
            body = {"instance_id": iid, "samples": [sample(first_seq + i) for i in range(200)]}
            assert (await c.post("/upper/update_param", headers=vh, json=body)).is_success
        read_end, write_end = os.pipe()
        env = {**os.environ, "FLEET_SERVER": base, "FLEET_TOKEN": ADMIN_TOKEN}
        exporter = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "remote_client.cli", "export", vid, "--page", "100",
            env=env, stdout=write_end, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        os.close(write_end)
        try:
            with os.fdopen(read_end, "rb") as head:
                first = await asyncio.to_thread(head.readline)
            async with asyncio.timeout(20):
                _, stderr = await exporter.communicate()
        finally:
            if exporter.returncode is None:
                exporter.kill()
                await exporter.wait()
    assert json.loads(first)["seq"] == 1
    assert exporter.returncode == 141, stderr
    assert stderr == b""


@pytest.mark.parametrize("command", [["vehicles"], ["users"], ["params", "{vid}"]])
async def test_a_table_whose_reader_has_gone_ends_with_141_as_a_line_does(
    make_settings: Callable[..., Settings], command: list[str]
) -> None:
    """``fleetctl vehicles | grep -q ...`` under ``pipefail``: the tables end as the line
    printers do (141, quiet), not as a refusal (1)."""
    async with served_vehicle(make_settings()) as (base, _c, vid, _vh, _iid):
        read_end, write_end = os.pipe()
        os.close(read_end)  # the reader has gone before the answer is printed
        env = {**os.environ, "FLEET_SERVER": base, "FLEET_TOKEN": ADMIN_TOKEN}
        args = [part.format(vid=vid) for part in command]
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "remote_client.cli", *args,
            env=env, stdout=write_end, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        os.close(write_end)
        async with asyncio.timeout(30):
            _, stderr = await proc.communicate()
    assert proc.returncode == 141, stderr
    assert stderr == b""


async def test_a_refused_export_leaves_the_file_it_was_to_write_as_it_was(
    make_settings: Callable[..., Settings], tmp_path: Path
) -> None:
    """A mistyped vehicle, a refusal or a lost server: the former file is kept, and no
    empty one is made."""
    async with served_vehicle(make_settings()) as (base, c, vid, vh, iid):
        body = {"instance_id": iid, "samples": [sample(seq) for seq in range(1, 6)]}
        assert (await c.post("/upper/update_param", headers=vh, json=body)).is_success
        kept = tmp_path / "kept.csv"
        assert (await fleetctl(base, ADMIN_TOKEN, "export", vid, "-o", str(kept))).exit_code == 0
        before = kept.read_text()

        typo = await fleetctl(base, ADMIN_TOKEN, "export", "no-such-vehicle", "-o", str(kept))
        assert typo.exit_code == 1 and "404" in typo.stderr
        assert kept.read_text() == before
        fresh = tmp_path / "fresh.csv"
        refused = await fleetctl(base, "fct_not-a-token", "export", vid, "-o", str(fresh))
        assert refused.exit_code == 1 and "401" in refused.stderr
        assert not fresh.exists()
        assert not (tmp_path / ".kept.csv.part").exists()  # nothing left over
        assert not (tmp_path / ".fresh.csv.part").exists()
