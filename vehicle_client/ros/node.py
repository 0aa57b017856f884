"""The ROS bridge process (run with the system python, which has rospy).

    /usr/bin/python3 -m vehicle_client.ros.node --listen 127.0.0.1:9311 \
        [--fix-topic /fleet/fix] [--pose-topic /fleet/pose] [--datum LAT,LON] \
        [--battery-topic /fleet/battery] [--status-topic /fleet/status] \
        [--local-topic /fleet/local_control] [--command-topic /fleet/command]

In: ``sensor_msgs/NavSatFix`` (position), ``geometry_msgs/PoseStamped``
(heading; position too, in ENU metres around ``--datum``),
``sensor_msgs/BatteryState``, ``std_msgs/String`` JSON reports
``{"type", "status", "progress"?, "detail"?}`` from the vehicle's
controller, ``std_msgs/Bool`` local control. Out: ``std_msgs/String`` JSON
commands ``{"command_id", "type", "args"}``. The agent connects over TCP
and reads ``state``/``report`` lines, and writes ``execute``/``halt`` lines.
"""

from __future__ import annotations

import argparse
import socket
import threading
import time

import rospy
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import BatteryState, NavSatFix
from std_msgs.msg import Bool, String

from vehicle_client.geo import LocalFrame
from vehicle_client.ros import mapping

STATE_EVERY_S = 0.2


class Bridge:
    def __init__(self, args: argparse.Namespace) -> None:
        self.state = mapping.VehicleState()
        self.datum = LocalFrame(*map(float, args.datum.split(","))) if args.datum else None
        self.lock = threading.Lock()
        self.conn: socket.socket | None = None
        self.commands = rospy.Publisher(args.command_topic, String, queue_size=10)
        rospy.Subscriber(args.fix_topic, NavSatFix, self.on_fix)
        rospy.Subscriber(args.pose_topic, PoseStamped, self.on_pose)
        rospy.Subscriber(args.battery_topic, BatteryState, self.on_battery)
        rospy.Subscriber(args.status_topic, String, self.on_status)
        rospy.Subscriber(args.local_topic, Bool, self.on_local)

    # -- ROS in ---------------------------------------------------------------
    def on_fix(self, msg: NavSatFix) -> None:
        self.state.on_fix(mapping.fix_fields(msg.status.status, msg.latitude, msg.longitude))

    def on_pose(self, msg: PoseStamped) -> None:
        p, o = msg.pose.position, msg.pose.orientation
        self.state.on_pose(mapping.pose_fields(self.datum, p.x, p.y, p.z, (o.x, o.y, o.z, o.w)))

    def on_battery(self, msg: BatteryState) -> None:
        self.state.on_battery(msg.percentage)

    def on_local(self, msg: Bool) -> None:
        self.state.local_control = bool(msg.data)

    def on_status(self, msg: String) -> None:
        report = mapping.parse_status(msg.data)
        if report is not None:
            self.send({"op": "report", **report})

    # -- agent link -------------------------------------------------------------
    def send(self, message: dict) -> None:
        with self.lock:
            if self.conn is None:
                return
            try:
                self.conn.sendall(mapping.encode(message))
            except OSError:
                self.conn = None

    def serve(self, host: str, port: int) -> None:
        server = socket.create_server((host, port), reuse_port=False)
        server.settimeout(0.5)
        while not rospy.is_shutdown():
            try:
                conn, _ = server.accept()
            except TimeoutError:
                continue
            with self.lock:
                self.conn = conn
            threading.Thread(target=self.read, args=(conn,), daemon=True).start()

    def read(self, conn: socket.socket) -> None:
        for line in conn.makefile("rb"):
            message = mapping.decode(line)
            if message is None:
                continue
            if message["op"] == "execute":
                text = mapping.command_text(
                    message.get("kind", ""), message.get("args") or {}, message.get("command_id")
                )
                self.commands.publish(String(data=text))
            elif message["op"] == "halt":
                self.commands.publish(String(data=mapping.command_text("stop", {}, None)))

    def tick(self) -> None:
        while not rospy.is_shutdown():
            fields = self.state.fields()
            self.send({"op": "state", "fields": fields, "local_control": self.state.local_control})
            time.sleep(STATE_EVERY_S)


def main() -> None:
    ap = argparse.ArgumentParser(description="fleet-agent's ROS bridge")
    ap.add_argument("--listen", default="127.0.0.1:9311")
    ap.add_argument("--fix-topic", default="/fleet/fix")
    ap.add_argument("--pose-topic", default="/fleet/pose")
    ap.add_argument("--battery-topic", default="/fleet/battery")
    ap.add_argument("--status-topic", default="/fleet/status")
    ap.add_argument("--local-topic", default="/fleet/local_control")
    ap.add_argument("--command-topic", default="/fleet/command")
    ap.add_argument("--datum", default="", help="LAT,LON of the pose frame's origin")
    args = ap.parse_args(rospy.myargv()[1:])
    rospy.init_node("fleet_bridge", anonymous=True, disable_signals=False)
    bridge = Bridge(args)
    host, port = args.listen.rsplit(":", 1)
    threading.Thread(target=bridge.tick, daemon=True).start()
    bridge.serve(host, int(port))


if __name__ == "__main__":
    main()
