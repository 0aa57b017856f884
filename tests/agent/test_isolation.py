"""A vehicle installs ``.[agent]`` alone: the agent never imports the server's stack."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

PROBE = """
import importlib, pkgutil, sys
FORBIDDEN = ("server", "fastapi", "pymongo", "mongomock", "uvicorn", "starlette")

class Block:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in FORBIDDEN:
            raise ImportError(f"the agent imported {name}")
        return None

sys.meta_path.insert(0, Block())
import vehicle_client
for mod in pkgutil.walk_packages(vehicle_client.__path__, "vehicle_client."):
    if ".ros." in mod.name + "." and mod.name.endswith(("node", "ros_io")):
        continue  # runs under the system python with rospy, outside the agent
    importlib.import_module(mod.name)
print("ok")
"""


def test_every_agent_module_imports_without_the_server_stack() -> None:
    result = subprocess.run(
        [sys.executable, "-c", PROBE], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip() == "ok"
