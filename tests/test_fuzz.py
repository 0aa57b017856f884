"""schemathesis over the whole OpenAPI document of a real fleet-server, as an admin, an
operator and a vehicle: no answer is a 5xx, every status is documented and every body
matches its declared schema. Bounded in time (``FUZZ_SECONDS`` per principal); at least
1,000 generated cases in all."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from tests.agent.procs import ADMIN_TOKEN, ServerProcess

pytestmark = pytest.mark.slow

FUZZ_SECONDS = int(os.environ.get("FLEET_FUZZ_SECONDS", "30"))
CHECKS = "not_a_server_error,status_code_conformance,response_schema_conformance"


def principals(server: ServerProcess) -> dict[str, str]:
    """Tokens of an admin, an operator of one vehicle, and that vehicle."""
    admin = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
    with httpx.Client(base_url=server.url, timeout=10) as c:
        r = c.post("/api/vehicles", headers=admin, json={"vehicle_id": "usv-1"})
        r.raise_for_status()
        vehicle = r.json()["token"]
        r = c.post(
            "/upper/start_instance",
            headers={"Authorization": f"Bearer {vehicle}"},
            json={"vehicle_id": "usv-1", "capabilities": ["stop", "go_to"]},
        )
        r.raise_for_status()
        r = c.post(
            "/api/users",
            headers=admin,
            json={"username": "ana", "role": "operator", "vehicles": ["usv-1"]},
        )
        r.raise_for_status()
        operator = r.json()["token"]
    return {"admin": ADMIN_TOKEN, "operator": operator, "vehicle": vehicle}


def test_schemathesis_finds_no_5xx_and_no_answer_off_the_document(tmp_path: Path) -> None:
    server = ServerProcess(tmp_path)
    server.env.update(FLEET_RATE_LIMIT_PER_S="100000", FLEET_RATE_LIMIT_BURST="100000")
    server.start()
    generated = 0
    try:
        for role, token in principals(server).items():
            run = subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "schemathesis.cli",
                    "run",
                    f"{server.url}/openapi.json",
                    "-H",
                    f"Authorization: Bearer {token}",
                    "--checks",
                    CHECKS,
                    "--max-time",
                    str(FUZZ_SECONDS),
                    # Past get_control's longest long poll (wait_s up to 30, which the
                    # vehicle's instance id found by the stateful phase makes it wait):
                    # such an answer is on time, not a network error.
                    "--request-timeout",
                    "35",
                    "--seed",
                    "1",
                ],
                capture_output=True,
                text=True,
                timeout=FUZZ_SECONDS * 4 + 60,
                cwd=tmp_path,
                check=False,
            )
            out = run.stdout + run.stderr
            found = re.search(r"(\d+) generated", out)
            assert found is not None, out[-3000:]
            generated += int(found.group(1))
            assert run.returncode == 0, f"as {role}:\n{out[-6000:]}"
    finally:
        server.stop()
    log = (tmp_path / "server.log").read_text()
    assert "Traceback" not in log, log[-3000:]
    assert generated >= 1000, generated
