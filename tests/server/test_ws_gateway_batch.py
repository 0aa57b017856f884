"""A gateway's batches on /ws/vehicle, end to end: ops for its vehicles, one refused
without holding up the others, answers in the order sent."""

from __future__ import annotations

import json

import httpx
import pytest

from tests.factories import ADMIN, make_vehicle, sample
from tests.live import call, connect, recv_until
from tests.server.commanding import ALL_CAPABILITIES as CAPS

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


async def _gateway(api: httpx.AsyncClient, gateway_id: str, vehicles: list[str]) -> str:
    """A gateway for ``vehicles``: its token."""
    r = await api.post(
        "/api/gateways", headers=ADMIN, json={"gateway_id": gateway_id, "vehicles": vehicles}
    )
    assert r.status_code == 201, r.text
    return str(r.json()["token"])


async def test_gateway_batches_ops_for_its_vehicles(base: str, api: httpx.AsyncClient) -> None:
    v1, _ = await make_vehicle(api)
    v2, _ = await make_vehicle(api)
    v3, _ = await make_vehicle(api)
    gw = await _gateway(api, "gw-ws", [v1, v2])
    async with await connect(base, "/ws/vehicle", gw) as ws:
        await ws.send(
            json.dumps(
                {
                    "op": "batch",
                    "id": "b1",
                    "ops": [
                        {"op": "start_instance", "id": "a", "vehicle_id": v1, "capabilities": CAPS},
                        {"op": "start_instance", "id": "b", "vehicle_id": v2, "capabilities": CAPS},
                        {"op": "start_instance", "id": "c", "vehicle_id": v3, "capabilities": CAPS},
                    ],
                }
            )
        )
        acks = {}
        while len(acks) < 4:
            frame = await recv_until(ws, lambda f: f["op"] == "ack")
            acks[frame["id"]] = frame
        assert acks["a"]["ok"] and acks["b"]["ok"]
        assert acks["c"]["ok"] is False and acks["c"]["error"]["code"] == "forbidden"
        assert acks["b1"]["ok"] is True


async def test_one_bad_op_in_a_gateway_batch_does_not_hold_up_the_others(
    base: str, api: httpx.AsyncClient
) -> None:
    v1, _ = await make_vehicle(api)
    v2, _ = await make_vehicle(api)
    gw = await _gateway(api, "gw-part", [v1, v2])
    async with await connect(base, "/ws/vehicle", gw) as ws:
        i1 = await call(ws, "start_instance", "s1", vehicle_id=v1, capabilities=CAPS)
        i2 = await call(ws, "start_instance", "s2", vehicle_id=v2, capabilities=CAPS)
        bad = sample(2)
        bad["ts"] = "not a time"
        ops = [
            {
                "op": "update_param",
                "id": "u1",
                "instance_id": i1["instance_id"],
                "samples": [sample(1)],
            },
            {
                "op": "update_param",
                "id": "u2",
                "instance_id": i2["instance_id"],
                "samples": [sample(1), bad],
            },
            {"op": "heartbeat", "id": "h2", "instance_id": i2["instance_id"]},
        ]
        await ws.send(json.dumps({"op": "batch", "id": "b1", "ops": ops}))
        acks = {}
        while len(acks) < 4:
            got = await recv_until(ws, lambda f: f["op"] == "ack")
            acks[got["id"]] = got
        assert acks["u1"]["ok"] is True and acks["u1"]["accepted"] == 1
        assert acks["h2"]["ok"] is True
        assert acks["u2"]["ok"] is False
        assert acks["u2"]["error"]["details"][0]["field"] == "samples.1.ts"
        assert acks["b1"]["ok"] is True
        assert (acks["b1"]["count"], acks["b1"]["refused"]) == (2, 1)
    r = await api.get(f"/api/vehicles/{v1}/telemetry", headers=ADMIN)
    assert [s["seq"] for s in r.json()["samples"]] == [1]
    r = await api.get(f"/api/vehicles/{v2}/telemetry", headers=ADMIN)
    assert r.json()["samples"] == []  # its op was refused whole, as alone


async def test_the_ops_of_a_batch_are_answered_in_the_order_sent(
    base: str, api: httpx.AsyncClient
) -> None:
    """Valid, refused on running (an unknown instance), refused on reading (an unknown op,
    an op without id): each answered in its place, then the batch's own ack."""
    v1, _ = await make_vehicle(api)
    gw = await _gateway(api, "gw-order", [v1])
    async with await connect(base, "/ws/vehicle", gw) as ws:
        i1 = (await call(ws, "start_instance", "s1", vehicle_id=v1, capabilities=CAPS))[
            "instance_id"
        ]
        ops = [
            {"op": "heartbeat", "id": "b1", "instance_id": i1},
            {"op": "heartbeat", "id": "b2", "instance_id": "i-nobody"},
            {"op": "no_such_op", "id": "b3"},
            {"op": "heartbeat", "instance_id": 5},
            {"op": "heartbeat", "id": "b5", "instance_id": i1},
        ]
        await ws.send(json.dumps({"op": "batch", "id": "b", "ops": ops}))
        answers = []
        while not answers or answers[-1].get("id") != "b":
            answers.append(await recv_until(ws, lambda f: f["op"] in ("ack", "error")))
    assert [(a["op"], a.get("id"), a.get("ok")) for a in answers] == [
        ("ack", "b1", True),
        ("ack", "b2", False),
        ("ack", "b3", False),
        ("error", None, None),
        ("ack", "b5", True),
        ("ack", "b", True),
    ]
    assert answers[1]["error"]["code"] == "not_found"
    assert answers[2]["error"]["details"][0]["field"] == "op"
    assert answers[3]["error"]["details"][0]["field"] == "instance_id"
    assert (answers[-1]["count"], answers[-1]["refused"]) == (3, 2)
