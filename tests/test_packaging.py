"""The compose file and the package layout, checked as far as this machine allows.

No Docker engine runs here: the compose file is parsed and its services
checked, never run.
"""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent


def test_compose_has_mongo_with_healthcheck_and_server_depending_on_it() -> None:
    compose = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
    services = compose["services"]
    assert services["mongo"]["image"].startswith("mongo:")
    assert "healthcheck" in services["mongo"]
    server = services["server"]
    assert server["depends_on"]["mongo"]["condition"] == "service_healthy"
    assert server["ports"] == ["8000:8000"]
    assert server["environment"]["FLEET_MONGO_URL"].startswith("mongodb://mongo:")
    assert server["build"] == "."


def test_dockerfile_runs_the_server_on_port_8000() -> None:
    text = (ROOT / "Dockerfile").read_text()
    assert "EXPOSE 8000" in text and 'CMD ["fleet-server"]' in text


def test_extras_keep_the_agent_light() -> None:
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    agent = " ".join(meta["optional-dependencies"]["agent"])
    for heavy in ("fastapi", "pymongo", "mongomock", "shapely", "uvicorn", "matplotlib"):
        assert heavy not in agent
    assert any(d.startswith("matplotlib") for d in meta["optional-dependencies"]["operator"])
    assert set(meta["scripts"]) == {"fleet-server", "fleet-agent", "fleetctl"}


def test_vehicle_client_never_imports_the_server() -> None:
    code = (
        "import sys, vehicle_client, vehicle_client.cli, fleet_protocol;"
        "bad = [m for m in sys.modules if m.split('.')[0] in "
        "('server', 'fastapi', 'pymongo', 'mongomock', 'mongomock_motor')];"
        "print(bad); sys.exit(1 if bad else 0)"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stdout + r.stderr


def test_fleet_server_help_lists_every_setting() -> None:
    r = subprocess.run(
        [sys.executable, "-m", "server.cli", "--help"], capture_output=True, text=True, cwd=ROOT
    )
    assert r.returncode == 0
    for name in (
        "FLEET_MONGO_URL",
        "FLEET_DB_NAME",
        "FLEET_SNAPSHOT_PATH",
        "FLEET_REDIS_URL",
        "FLEET_HOST",
        "FLEET_PORT",
        "FLEET_ADMIN_TOKEN",
        "FLEET_HEARTBEAT_INTERVAL_S",
        "FLEET_STALE_AFTER_S",
        "FLEET_OFFLINE_AFTER_S",
        "FLEET_ACK_TIMEOUT_S",
        "FLEET_SAFETY_RADIUS_M",
        "FLEET_RETENTION_S",
        "FLEET_MAX_BODY_BYTES",
    ):
        assert name in r.stdout, name
