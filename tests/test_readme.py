"""The README's command blocks, run as written against ``make demo`` (``python -m
server.demo`` in a scratch folder), so that they cannot drift from what the tools do.

The blocks are read from README.md itself: the one under "One minute with fleetctl"
(the placeholder for the admin token filled in with the token the demo printed), and
the one under "The vehicle agent" (its ``fleet-agent run`` kept running until its
vehicle is online), and docs/agent.md's gateway block (until its three vehicles are
online). The demo runs on a free port: ``FLEET_SERVER`` and the agent's
``--server`` point there instead of the README's ``http://127.0.0.1:8000``.
"""

from __future__ import annotations

import os
import re
import sqlite3
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from remote_client.tracks import GPX_NS
from tests.agent.procs import free_port, wait_until
from tests.demo_run import admin_token, start_demo, stop_demo, vehicles, wait_online

ROOT = Path(__file__).resolve().parent.parent
PLACEHOLDER = "<the admin token make demo printed>"
#: Where the README's server is (the demo's default); the test's demo is on a free port.
README_SERVER = "http://127.0.0.1:8000"
DEMO_VEHICLES = ["demo-usv-1", "demo-usv-2", "demo-usv-3"]


def sh_block(heading: str, doc: str = "README.md") -> list[str]:
    """The lines of the first ``sh`` block under ``heading`` in ``doc``, continuation
    lines joined."""
    text = (ROOT / doc).read_text()
    after = text[text.index(f"\n{heading}\n") :]
    found = re.search(r"```sh\n(.*?)```", after, re.S)
    assert found, f"no sh block under {heading}"
    return found.group(1).replace("\\\n", " ").splitlines()


def bash(script: str, folder: Path, env: dict[str, str], within_s: float = 120) -> str:
    """Run ``script`` with bash, stopping at the first failing command; its stdout."""
    done = subprocess.run(
        ["bash", "-c", "set -euo pipefail\n" + script],
        cwd=folder,
        env=env,
        capture_output=True,
        text=True,
        timeout=within_s,
    )
    assert done.returncode == 0, f"exit {done.returncode}\n{done.stdout}\n{done.stderr}"
    return done.stdout


def _started(script: str, folder: Path, env: dict[str, str]) -> subprocess.Popen[str]:
    """A block whose last command runs on (an agent, a gateway), started with bash."""
    return subprocess.Popen(
        ["bash", "-c", "set -euo pipefail\n" + script],
        cwd=folder,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


def _running(proc: subprocess.Popen[str]) -> None:
    """Still running (else its stderr says why it stopped)."""
    assert proc.stderr is not None
    assert proc.poll() is None, proc.stderr.read()


@pytest.fixture
def demo_folder(tmp_path: Path) -> Path:
    """A scratch folder standing for the repository's top: ``.venv`` is this venv."""
    (tmp_path / ".venv").symlink_to(sys.prefix, target_is_directory=True)
    assert (tmp_path / ".venv" / "bin" / "fleetctl").exists(), "pip install -e '.[all]' first"
    return tmp_path


def test_the_readme_walk_through_and_the_agent_path_work_as_written(demo_folder: Path) -> None:
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    demo = start_demo(demo_folder, port, demo_folder / "demo.log")
    agent: subprocess.Popen[str] | None = None
    try:
        token = admin_token(demo_folder / "demo.log")
        wait_online(base, token, DEMO_VEHICLES)
        env = {**os.environ, "FLEET_SERVER": base}
        env.pop("FLEET_TOKEN", None)

        walk = sh_block("## One minute with fleetctl")
        assert any(PLACEHOLDER in line for line in walk)
        out = bash("\n".join(walk).replace(PLACEHOLDER, token), demo_folder, env)

        vehicle_rows = [line for line in out.splitlines() if "demo-usv-" in line and "│" in line]
        assert all("online" in row for row in vehicle_rows[:3]), out
        assert "admin holds H2OmniX Alpha (demo-usv-1) until" in out
        assert re.search(r"H2OmniX Alpha \(i-\w+\): c-\w+ queued", out)  # the go_to, by name
        samples = re.findall(r"^(?:current|\d\d:\d\d:\d\dZ) demo-usv-1 telemetry #\d+ ", out, re.M)
        assert len(samples) == 3
        assert "go_to" in out and "command by admin go_to" in out  # commands and events
        trkpts = ET.parse(demo_folder / "alpha.gpx").getroot().findall(f".//{{{GPX_NS}}}trkpt")
        assert trkpts
        assert (demo_folder / "alpha.png").read_bytes().startswith(b"\x89PNG\r\n\x1a\n")
        synced = re.findall(r"^(demo-usv-\d): (\d+) new samples?", out, re.M)
        assert [vid for vid, _ in synced] == [*DEMO_VEHICLES, "demo-usv-1"]
        assert all(int(n) > 0 for _, n in synced[:3])
        assert int(synced[3][1]) < int(synced[0][1])  # the second run: only what is new
        with sqlite3.connect(demo_folder / "fleet.sqlite") as copy:
            held = dict(copy.execute("SELECT vehicle_id, count(*) FROM samples GROUP BY 1"))
        assert set(held) == set(DEMO_VEHICLES)
        queued = re.findall(r"^H2OmniX \w+ \(i-\w+\): c-\w+ queued", out, re.M)
        assert len(queued) >= 4  # goto, then 3 stops

        # The agent's block: a vehicle registered, its agent run with the token printed,
        # then a new token (the agent's stops working) and every token revoked.
        lines = sh_block("## The vehicle agent")
        at = next(i for i, line in enumerate(lines) if line.startswith("fleet-agent run"))
        # The same terminal: the venv active, FLEET_TOKEN set.
        bin_dir = str(demo_folder / ".venv" / "bin")
        env = {**env, "FLEET_TOKEN": token, "PATH": bin_dir + os.pathsep + env["PATH"]}
        script = "\n".join([*lines[:at], "exec " + lines[at]]).replace(README_SERVER, base)
        agent = _started(script, demo_folder, env)

        def online() -> bool:
            _running(agent)
            return vehicles(base, token).get("usv-4", {}).get("presence") == "online"

        wait_until(online, "usv-4 online, its agent run as the README says", 60)
        assert vehicles(base, token)["usv-4"]["name"] == "Delta"
        bash("\n".join(lines[at + 1 :]), demo_folder, env)
        assert agent.wait(timeout=30) == 2  # refused by the server: its token was replaced

        # docs/agent.md's gateway: three vehicles added, a gateway token, the gateway run.
        lines = sh_block("## A surface gateway", "docs/agent.md")
        (demo_folder / "examples").mkdir()
        (demo_folder / "examples" / "gateway.toml").write_text(
            (ROOT / "examples" / "gateway.toml").read_text()
        )
        script = "\n".join([*lines[:-1], "exec " + lines[-1]]).replace(README_SERVER, base)
        agent = _started(script, demo_folder, env)

        def gateway_online() -> bool:
            _running(agent)
            seen = vehicles(base, token)
            return all(
                seen.get(v, {}).get("presence") == "online" for v in ("usv-1", "usv-2", "usv-3")
            )

        wait_until(gateway_online, "usv-1..3 online through the gateway of docs/agent.md", 60)
        assert vehicles(base, token)["usv-2"]["name"] == "Omni 2"
    finally:
        if agent is not None and agent.poll() is None:
            agent.kill()
        stop_demo(demo)
