"""The ROS bridge: ROS kept in its own small process, apart from the agent.

- ``node``: the bridge process, run with the system ``/usr/bin/python3``
  (Debian's ``python3-rospy``); it maps configured ROS topics to a local
  line protocol (JSON lines over TCP on 127.0.0.1).
- ``adapter``: the agent's side of that protocol (``--adapter ros``).
- ``mapping``: what turns ROS messages into samples and commands into ROS
  messages; pure and stdlib-only so that both sides (and tests) use it.
"""
