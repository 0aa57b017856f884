"""Each program runs as its installed command and as ``python -m <package>`` alike
(``python -m vehicle_client`` said "No module named vehicle_client.__main__")."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize(
    ("package", "said"),
    [
        ("server", "Run the fleet-cloud server"),
        ("vehicle_client", "fleet-agent"),
        ("remote_client", "Operate a fleet-cloud fleet"),
    ],
)
def test_python_dash_m_runs_the_package_s_program(package: str, said: str) -> None:
    run = subprocess.run(
        [sys.executable, "-m", package, "--help"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
        env={**os.environ, "COLUMNS": "120"},
        check=False,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert said in run.stdout
