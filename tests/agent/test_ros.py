"""The ROS bridge: pure mapping, the agent's adapter over the line protocol, and a real roscore."""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import os
import shutil
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from vehicle_client.geo import LocalFrame
from vehicle_client.ros import mapping
from vehicle_client.ros.adapter import RosAdapter

ROOT = Path(__file__).resolve().parents[2]
SYSTEM_PYTHON = "/usr/bin/python3"


def q_yaw(yaw_deg: float) -> tuple[float, float, float, float]:
    half = math.radians(yaw_deg) / 2
    return (0.0, 0.0, math.sin(half), math.cos(half))


@pytest.mark.parametrize(("yaw", "heading"), [(0, 90), (90, 0), (180, 270), (-90, 180)])
def test_enu_yaw_becomes_a_compass_heading(yaw: float, heading: float) -> None:
    assert mapping.yaw_to_heading_deg(*q_yaw(yaw)) == pytest.approx(heading % 360, abs=1e-9)


def test_a_navsatfix_without_a_fix_gives_no_position() -> None:
    assert mapping.fix_fields(-1, 43.9, 15.4) is None
    assert mapping.fix_fields(0, math.nan, 15.4) is None
    assert mapping.fix_fields(0, 43.9, 15.4) == {"lat": 43.9, "lon": 15.4}


def test_a_pose_around_a_datum_gives_position_heading_and_depth() -> None:
    datum = LocalFrame(43.94, 15.44)
    fields = mapping.pose_fields(datum, 100.0, 0.0, -2.5, q_yaw(90))
    assert fields["heading_deg"] == pytest.approx(0.0)
    assert fields["depth_m"] == 2.5
    assert datum.to_enu(fields["lat"], fields["lon"])[0] == pytest.approx(100.0)
    assert "lat" not in mapping.pose_fields(None, 1.0, 2.0, 0.0, q_yaw(0))


def test_state_merges_inputs_the_fix_winning_and_needs_a_position() -> None:
    state = mapping.VehicleState()
    state.on_pose({"heading_deg": 12.0})
    state.on_battery(0.5)
    assert state.fields() is None
    state.on_pose({"heading_deg": 12.0, "lat": 1.0, "lon": 1.0})
    state.on_fix({"lat": 43.9, "lon": 15.4})
    assert state.fields() == {"heading_deg": 12.0, "battery_pct": 50.0, "lat": 43.9, "lon": 15.4}


def test_status_reports_are_checked() -> None:
    ok = mapping.parse_status('{"type": "go_to", "status": "done", "progress": 1}')
    assert ok == {"kind": "go_to", "status": "done", "progress": 1, "detail": None}
    assert mapping.parse_status('{"type": "go_to", "status": "accepted"}') is None
    assert mapping.parse_status("not json") is None
    odd = mapping.parse_status('{"type": "go_to", "status": "executing", "progress": 7}')
    assert odd is not None and odd["progress"] is None


def test_commands_and_lines_round_trip() -> None:
    text = mapping.command_text("go_to", {"lat": 1.0, "lon": 2.0}, "c1")
    assert json.loads(text) == {
        "command_id": "c1",
        "type": "go_to",
        "args": {"lat": 1.0, "lon": 2.0},
    }
    assert mapping.decode(mapping.encode({"op": "halt"})) == {"op": "halt"}
    assert mapping.decode(b"[1, 2]") is None


async def test_the_adapter_speaks_the_bridge_protocol() -> None:
    received: asyncio.Queue[dict] = asyncio.Queue()
    peer: dict[str, asyncio.StreamWriter] = {}
    accepted = asyncio.Event()

    async def bridge(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peer["w"] = writer
        accepted.set()
        while line := await reader.readline():
            await received.put(json.loads(line))

    server = await asyncio.start_server(bridge, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    adapter = RosAdapter(f"127.0.0.1:{port}")
    task = asyncio.create_task(adapter.run())
    try:
        await asyncio.wait_for(adapter.connected.wait(), 10)
        await asyncio.wait_for(accepted.wait(), 10)
        state = {"op": "state", "fields": {"lat": 43.9, "lon": 15.4}, "local_control": True}
        peer["w"].write(mapping.encode(state))
        adapter.execute("go_to", {"lat": 43.91, "lon": 15.41}, "c-7")
        sent = await asyncio.wait_for(received.get(), 10)
        assert sent == {
            "op": "execute", "kind": "go_to", "args": {"lat": 43.91, "lon": 15.41},
            "command_id": "c-7",
        }  # fmt: skip
        peer["w"].write(mapping.encode({"op": "report", "kind": "go_to", "status": "done"}))
        for _ in range(500):
            if adapter.report() is not None:
                break
            await asyncio.sleep(0.01)
        assert adapter.report().status == "done"  # type: ignore[union-attr]
        assert adapter.telemetry() == {"lat": 43.9, "lon": 15.4}
        assert adapter.local_control is True
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        server.close()


def test_a_bad_bridge_address_is_refused() -> None:
    with pytest.raises(ValueError, match="HOST:PORT"):
        RosAdapter("localhost")


# -- a real roscore ---------------------------------------------------------------


def _has_ros() -> bool:
    if shutil.which("roscore") is None or not os.path.exists(SYSTEM_PYTHON):
        return False
    imports = "import rospy, geometry_msgs.msg, sensor_msgs.msg, std_msgs.msg"
    probe = subprocess.run([SYSTEM_PYTHON, "-c", imports], capture_output=True)
    return probe.returncode == 0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


TEST_NODE = """
import json, sys, rospy
from sensor_msgs.msg import NavSatFix
from std_msgs.msg import String
out = open(sys.argv[1], "a")
rospy.init_node("fleet_test_vehicle", anonymous=True)
status = rospy.Publisher("/fleet/status", String, queue_size=10)
def on_command(msg):
    out.write(msg.data + "\\n"); out.flush()
    cmd = json.loads(msg.data)
    status.publish(String(data=json.dumps({"type": cmd["type"], "status": "done"})))
rospy.Subscriber("/fleet/command", String, on_command)
fix = rospy.Publisher("/fleet/fix", NavSatFix, queue_size=10)
rate = rospy.Rate(10)
while not rospy.is_shutdown():
    m = NavSatFix(); m.latitude = 43.9412; m.longitude = 15.4423; m.status.status = 0
    fix.publish(m); rate.sleep()
"""


@pytest.fixture
def ros_world(tmp_path: Path) -> Iterator[tuple[int, Path]]:
    """roscore, the bridge node and a tiny vehicle node; the bridge's port and the commands file."""
    master, bridge_port = _free_port(), _free_port()
    env = {
        **os.environ,
        "ROS_MASTER_URI": f"http://127.0.0.1:{master}",
        "ROS_HOSTNAME": "127.0.0.1",
        "ROS_HOME": str(tmp_path),
        "PYTHONPATH": str(ROOT),
    }
    seen = tmp_path / "commands.jsonl"
    (tmp_path / "node.py").write_text(TEST_NODE)
    bridge = ["-m", "vehicle_client.ros.node", "--listen", f"127.0.0.1:{bridge_port}"]
    procs = []
    try:
        for args in (
            ["roscore", "-p", str(master)],
            [SYSTEM_PYTHON, *bridge],
            [SYSTEM_PYTHON, str(tmp_path / "node.py"), str(seen)],
        ):
            log = (tmp_path / f"{len(procs)}.log").open("w")
            procs.append(subprocess.Popen(args, cwd=ROOT, env=env, stdout=log, stderr=log))
        yield bridge_port, seen
    finally:
        for proc in reversed(procs):
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()


@pytest.mark.slow
@pytest.mark.skipif(not _has_ros(), reason="no roscore, or rospy or its messages missing (ROS 1)")
async def test_a_pose_in_and_a_command_out_through_a_real_roscore(
    ros_world: tuple[int, Path],
) -> None:
    bridge_port, seen = ros_world
    adapter = RosAdapter(f"127.0.0.1:{bridge_port}")
    task = asyncio.create_task(adapter.run())
    try:
        deadline = time.monotonic() + 60
        while adapter.telemetry() is None:
            assert time.monotonic() < deadline, "no position came through the bridge"
            await asyncio.sleep(0.1)
        assert adapter.telemetry() == {"lat": 43.9412, "lon": 15.4423}
        adapter.execute("go_to", {"lat": 43.95, "lon": 15.45}, "c-ros")
        while adapter.report() is None:
            assert time.monotonic() < deadline, "no report came back through the bridge"
            await asyncio.sleep(0.1)
        assert adapter.report().status == "done"  # type: ignore[union-attr]
        commands = [json.loads(line) for line in seen.read_text().splitlines()]
        expected = {"command_id": "c-ros", "type": "go_to", "args": {"lat": 43.95, "lon": 15.45}}
        assert commands[0] == expected
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
