"""What the agent drives: a simulated vehicle, or a real one through the ROS bridge."""

from vehicle_client.adapters.base import Adapter
from vehicle_client.adapters.sim import SimAdapter

__all__ = ["Adapter", "SimAdapter"]
