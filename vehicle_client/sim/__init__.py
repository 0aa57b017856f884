"""A pure simulator of an omnidirectional surface vehicle (like the H2OmniX).

No I/O and no clock: the caller steps it with a ``dt``. ``dynamics`` moves
the hull, ``tasks`` turns a command into a desired velocity, and
``simulator`` ties them together around a local frame.
"""

from vehicle_client.sim.dynamics import Current, VehicleParams, VehicleState, step
from vehicle_client.sim.simulator import Simulator, TaskReport
from vehicle_client.sim.tasks import (
    FollowPathTask,
    GoToTask,
    KeepStationTask,
    StopTask,
    Task,
)

__all__ = [
    "Current",
    "FollowPathTask",
    "GoToTask",
    "KeepStationTask",
    "Simulator",
    "StopTask",
    "Task",
    "TaskReport",
    "VehicleParams",
    "VehicleState",
    "step",
]
