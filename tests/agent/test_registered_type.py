"""The vehicle type an admin registers is the one the fleet shows once the vehicle's agent
runs (``harbour.py``): the agent's adapters (the simulator, the ROS bridge) do not know
what hull they drive, so the agent announces none and the server keeps the registered
one."""

from __future__ import annotations

from tests.agent.harbour import Harbour


async def test_an_auv_registered_as_such_stays_an_auv_once_its_agent_runs(
    harbour: Harbour,
) -> None:
    h = harbour
    boat = await h.boat("auv-7", vehicle_type="auv")
    view = await h.call("GET", "/api/vehicles/auv-7")
    assert view["vehicle_type"] == "auv", view["vehicle_type"]
    connected = await h.call("POST", "/client/connect_instance", json={"vehicle_id": "auv-7"})
    assert connected["instance"]["instance_id"] == boat.instance_id
    assert connected["instance"]["vehicle_type"] == "auv"
