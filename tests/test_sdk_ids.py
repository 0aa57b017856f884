"""The SDK takes one id where it takes ids: a plain string is that one, never a list of
its characters."""

from __future__ import annotations

import httpx
import pytest

from remote_client.sdk import (
    FleetClient,
)
from tests.factories import (
    ADMIN_TOKEN,
    make_vehicle,
    sample,
    start_instance,
    unique,
)

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


async def test_stop_and_keep_station_take_one_instance_id_as_go_to_does(
    client: httpx.AsyncClient,
) -> None:
    """``stop(iid)`` and ``keep_station(iid)``, as ``go_to(iid, ...)``: the one instance
    (a str was taken as a list of its characters: 404 "no instance i", nothing stopped)."""
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    admin = FleetClient("http://test", ADMIN_TOKEN, client=client)
    await admin.grant_control(iid, "admin", 600)

    held = await admin.keep_station(iid, radius_m=4.0)
    assert [c["instance_id"] for c in held["commands"]] == [iid]
    stopped = await admin.stop(iid)
    assert [c["instance_id"] for c in stopped["commands"]] == [iid]
    with pytest.raises(ValueError, match="no instance given"):
        await admin.keep_station([])


async def test_one_id_given_as_a_string_is_one_id_everywhere(client: httpx.AsyncClient) -> None:
    """Where the SDK takes ids (a user's or a gateway's vehicles, a submit's instances,
    the parameter names read), a plain string is one id, not a list of its characters
    (``create_user(name, role, "usv4")`` was assigned vehicles u, s, v and 4)."""
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    body = {"instance_id": iid, "params": {"depth_limit": 5, "gain": 2}, "samples": [sample(1)]}
    assert (await client.post("/upper/update_param", headers=vh, json=body)).is_success
    admin = FleetClient("http://test", ADMIN_TOKEN, client=client)

    made = await admin.create_user(unique("ana"), "operator", vid)
    assert made["vehicles"] == [vid]
    moved = await admin.update_user(made["username"], vehicles=vid)
    assert moved["vehicles"] == [vid]
    gateway = await admin.create_gateway(unique("gw"), vid)
    assert gateway["vehicles"] == [vid]
    await admin.grant_control(iid, "admin", 600)
    sent = await admin.submit(iid, {"type": "stop", "args": {}})
    assert [c["instance_id"] for c in sent["commands"]] == [iid]
    assert (await admin.params(iid, "depth_limit"))["params"] == {"depth_limit": 5}
