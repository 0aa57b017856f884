"""A vehicle's parameters: merged call by call within their bounds, read back as the
vehicle last sent them."""

from __future__ import annotations

import asyncio

import httpx
import pytest

from tests.factories import ADMIN, make_vehicle, sample, start_instance

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


async def test_params_merge_and_position(client: httpx.AsyncClient) -> None:
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh, params={"mode": "survey", "gain": 2}))[
        "instance_id"
    ]
    r = await client.post(
        "/upper/update_param",
        headers=vh,
        json={
            "instance_id": iid,
            "params": {"gain": None, "depth_limit": 5},
            "samples": [sample(1, lat=43.9401), sample(2, lat=43.9402)],
        },
    )
    assert r.status_code == 200, r.text
    assert r.json()["accepted"] == 2
    got = (await client.get("/client/get_param", headers=ADMIN, params={"instance_id": iid})).json()
    assert got["params"] == {"mode": "survey", "depth_limit": 5}
    assert got["position"]["seq"] == 2 and got["position"]["lat"] == 43.9402
    some = (
        await client.get(
            "/client/get_param", headers=ADMIN, params={"instance_id": iid, "names": "mode"}
        )
    ).json()
    assert some["params"] == {"mode": "survey"}


async def test_a_vehicles_parameters_keep_their_bounds_across_calls(
    client: httpx.AsyncClient,
) -> None:
    """512 entries and 64 KiB of JSON, for one call's params and for what they add up to:
    past it, 422 naming ``params`` and nothing changed (its samples not taken either); a
    vehicle that starts again past it starts from the parameters it sends."""
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh, params={"mode": "survey"}))["instance_id"]

    async def update(params: dict[str, object], seq: int) -> httpx.Response:
        body = {"instance_id": iid, "params": params, "samples": [sample(seq)]}
        return await client.post("/upper/update_param", headers=vh, json=body)

    async def held() -> dict[str, object]:
        got = await client.get("/client/get_param", headers=ADMIN, params={"instance_id": iid})
        params: dict[str, object] = got.json()["params"]
        return params

    assert (await update({f"a{k}": k for k in range(500)}, 1)).status_code == 200
    r = await update({f"b{k}": k for k in range(20)}, 2)  # 521 in all
    assert r.status_code == 422 and r.json()["error"]["details"][0]["field"] == "params"
    assert "521 parameters" in r.json()["error"]["details"][0]["message"]
    assert len(await held()) == 501
    assert (await update({"a0": None, "a1": None}, 2)).status_code == 200  # nulls make room
    r = await update({"big": "x" * 70_000}, 3)  # one call's own bound
    assert r.status_code == 422 and "65536" in r.text
    halves = [{f"h{n}": "x" * 40_000} for n in range(2)]
    assert (await update(halves[0], 3)).status_code == 200
    r = await update(halves[1], 4)
    assert r.status_code == 422 and "bytes of JSON" in r.json()["error"]["details"][0]["message"]
    assert "h1" not in await held()
    again = await start_instance(client, vid, vh, params={**halves[1], "mode": "transit"})
    assert again["resumed"] is True
    assert sorted(await held()) == ["h1", "mode"]


async def test_parameters_read_while_the_record_is_being_written_are_the_latest(
    client: httpx.AsyncClient,
) -> None:
    """A vehicle's parameters, read as the replica writes the instance's record back to
    the store, came back as the store had them before the write (empty, the first time):
    seen under load on FerretDB. Each read after an update says that update or a later
    one, for as long as the record is written back (every 0.25 s) meanwhile."""
    vid, vh = await make_vehicle(client)
    iid = (await start_instance(client, vid, vh))["instance_id"]
    acknowledged = 0
    stale: list[tuple[int, object]] = []
    done = asyncio.Event()

    async def reader() -> None:
        while not done.is_set():  # each read ends: one cut off would hold the app's stop
            floor = acknowledged
            r = await client.get("/client/get_param", headers=ADMIN, params={"instance_id": iid})
            got = r.json()["params"].get("n")
            if floor and (got is None or got < floor):
                stale.append((floor, got))
            await asyncio.sleep(0)  # a read that never waits on the store lets others run

    readers = [asyncio.create_task(reader()) for _ in range(3)]
    try:
        deadline = asyncio.get_running_loop().time() + 3.0  # a dozen write-backs
        n = 0
        while asyncio.get_running_loop().time() < deadline:
            n += 1
            body = {"instance_id": iid, "params": {"n": n}}
            assert (await client.post("/upper/update_param", headers=vh, json=body)).is_success
            acknowledged = n
            await asyncio.sleep(0.01)  # the vehicle's cadence, not a wait for a result
    finally:
        done.set()
        await asyncio.gather(*readers)
    assert not stale, f"{len(stale)} reads older than the update before them: {stale[:5]}"
