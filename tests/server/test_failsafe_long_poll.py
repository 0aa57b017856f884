"""A failsafe policy set while the vehicle waits in a long poll reaches it at once (on
another replica: tests/bus/test_replicas_failsafe.py); a version it was told and has not
acknowledged does not end its next polls early (a client that never acknowledges is not
answered at once poll after poll)."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import Any

import httpx
import pytest

from server.settings import Settings
from tests.factories import ADMIN, make_vehicle
from tests.live import serve

pytestmark = pytest.mark.usefixtures("store_backend")

#: Far longer than a policy takes to arrive: a poll that lasts it was not woken.
WAIT_S = 12.0


async def _started(api: httpx.AsyncClient, vid: str, vh: dict[str, str]) -> str:
    body = {"vehicle_id": vid, "capabilities": ["stop", "keep_station"]}
    r = await api.post("/upper/start_instance", headers=vh, json=body)
    assert r.status_code == 200, r.text
    answer = r.json()
    fb = {"instance_id": answer["instance_id"], "failsafe_version": answer["failsafe"]["version"]}
    assert (await api.post("/upper/update_fbmessage", headers=vh, json=fb)).is_success
    return str(answer["instance_id"])


async def _poll(api: httpx.AsyncClient, iid: str, vh: dict[str, str], wait_s: float) -> Any:
    r = await api.get(
        "/upper/get_control", headers=vh, params={"instance_id": iid, "wait_s": wait_s}
    )
    assert r.status_code == 200, r.text
    return r.json()


async def _policy_set_during(
    poller: httpx.AsyncClient, setter: httpx.AsyncClient, vid: str, iid: str, vh: dict[str, str]
) -> dict[str, Any]:
    """A long poll on ``poller`` while ``setter`` sets a new policy; its answer."""
    poll = asyncio.create_task(_poll(poller, iid, vh, WAIT_S))
    policy = {"action": "stop", "after_s": 40.0}
    r = await setter.put(f"/api/vehicles/{vid}/failsafe", headers=ADMIN, json=policy)
    assert r.status_code == 200, r.text
    async with asyncio.timeout(WAIT_S / 2):  # not held to the end of the poll
        answer: dict[str, Any] = await poll
    return answer


async def test_a_policy_set_during_a_long_poll_ends_it(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base, timeout=30) as c:
        vid, vh = await make_vehicle(c)
        iid = await _started(c, vid, vh)
        answer = await _policy_set_during(c, c, vid, iid, vh)
        assert answer["commands"] == []
        assert answer["failsafe"]["action"] == "stop" and answer["failsafe"]["after_s"] == 40

        # Told and not acknowledged: the next poll waits as usual, and carries it again.
        began = time.monotonic()
        again = await _poll(c, iid, vh, 1.0)
        assert time.monotonic() - began >= 0.9
        assert again["failsafe"]["version"] == answer["failsafe"]["version"]
        fb = {"instance_id": iid, "failsafe_version": answer["failsafe"]["version"]}
        assert (await c.post("/upper/update_fbmessage", headers=vh, json=fb)).is_success
        assert (await _poll(c, iid, vh, 0))["failsafe"] is None


async def test_a_version_never_issued_is_not_taken_as_applied(
    make_settings: Callable[..., Settings],
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base, timeout=30) as c:
        vid, vh = await make_vehicle(c)
        iid = await _started(c, vid, vh)
        told = await c.get(f"/api/vehicles/{vid}/failsafe", headers=ADMIN)
        version = told.json()["failsafe"]["version"]
        ahead = {"instance_id": iid, "failsafe_version": version + 1}  # from another server
        assert (await c.post("/upper/update_fbmessage", headers=vh, json=ahead)).is_success
        policy = {"action": "stop", "after_s": 5.0}
        put = await c.put(f"/api/vehicles/{vid}/failsafe", headers=ADMIN, json=policy)
        assert put.json()["failsafe"]["version"] == version + 1
        assert put.json()["acked"] is False  # the vehicle was never told this one
        answer = await _poll(c, iid, vh, 0)
        assert answer["failsafe"]["version"] == version + 1 and answer["failsafe"]["after_s"] == 5
