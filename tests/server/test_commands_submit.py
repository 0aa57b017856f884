"""POST /client/submit_control: success, and each refusal, all or nothing."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable

import pytest

from server.settings import Settings
from tests.factories import ADMIN
from tests.server.commanding import GO_TO, STOP, World, world

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


@pytest.fixture
async def w(make_settings: Callable[..., Settings]) -> AsyncIterator[World]:
    async with world(make_settings()) as w:
        yield w


async def test_the_holder_queues_a_command_and_the_vehicle_gets_it(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    r = await w.submit(op, [v], GO_TO)
    assert r.status_code == 202
    [queued] = r.json()["commands"]
    assert queued["instance_id"] == v.instance_id
    assert queued["status"] == "queued"
    [got] = await w.poll(v)
    assert got["command_id"] == queued["command_id"]
    assert got["type"] == "go_to"
    assert got["args"] == GO_TO["args"]
    assert got["issued_by"] == op.username
    assert got["status"] == "delivered"
    assert (await w.command(got["command_id"]))["status"] == "delivered"


async def test_without_a_token_it_is_401(w: World) -> None:
    v = await w.vehicle()
    r = await w.submit({}, [v], STOP)
    assert r.status_code == 401
    assert r.json()["error"]["code"] == "unauthorized"


async def test_a_viewer_or_a_vehicle_cannot_submit(w: World) -> None:
    v = await w.vehicle()
    viewer = await w.person("viewer", v)
    for who in (viewer.headers, v.headers):
        r = await w.submit(who, [v], STOP)
        assert r.status_code == 403, r.text
        assert r.json()["error"]["code"] == "forbidden"


async def test_an_operator_without_access_to_the_vehicle_is_refused(w: World) -> None:
    v = await w.vehicle()
    stranger = await w.person("operator")
    r = await w.submit(stranger, [v], STOP)
    assert r.status_code == 404  # as for an instance that does not exist (docs/security.md)
    assert r.json()["error"]["details"][0]["instance_id"] == v.instance_id


async def test_without_a_lease_it_is_409_control_not_held(w: World) -> None:
    v = await w.vehicle()
    op = await w.person("operator", v)
    r = await w.submit(op, [v], GO_TO)
    assert r.status_code == 409
    assert r.json()["error"]["code"] == "control_not_held"


async def test_an_admin_holds_no_control_without_a_lease(w: World) -> None:
    v = await w.vehicle()
    r = await w.submit(ADMIN, [v], GO_TO)
    assert r.status_code == 409
    assert r.json()["error"]["code"] == "control_not_held"


async def test_while_another_holds_the_lease_it_is_409(w: World) -> None:
    v = await w.vehicle()
    await w.operator_in_control(v)
    other = await w.person("operator", v)
    r = await w.submit(other, [v], GO_TO)
    assert r.status_code == 409
    assert r.json()["error"]["code"] == "control_not_held"


async def test_any_operator_with_access_may_always_stop(w: World) -> None:
    v = await w.vehicle()
    await w.operator_in_control(v)
    other = await w.person("operator", v)
    r = await w.submit(other, [v], STOP)
    assert r.status_code == 202, r.text


async def test_under_local_control_only_stop_passes(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    await w.ack(v, control_mode="local")
    r = await w.submit(op, [v], GO_TO)
    assert r.status_code == 409
    assert r.json()["error"]["code"] == "vehicle_local_control"
    assert (await w.submit(op, [v], STOP)).status_code == 202
    await w.ack(v, control_mode="remote")
    assert (await w.submit(op, [v], GO_TO)).status_code == 202


async def test_a_type_the_vehicle_lacks_is_422_capability_missing(w: World) -> None:
    v = await w.vehicle(capabilities=["go_to"])
    op = await w.operator_in_control(v)
    r = await w.submit(op, [v], {"type": "keep_station", "args": {}})
    assert r.status_code == 422
    assert r.json()["error"]["code"] == "capability_missing"


async def test_every_vehicle_can_stop_whatever_its_capabilities(w: World) -> None:
    v = await w.vehicle(capabilities=[])
    op = await w.person("operator", v)
    assert (await w.submit(op, [v], STOP)).status_code == 202


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({"command": {"type": "go_to", "args": {"lat": 100, "lon": 0}}}, "command.args.lat"),
        ({"command": {"type": "go_to", "args": {"lat": 1}}}, "command.args.lon"),
        ({"command": {"type": "fly", "args": {}}}, "command.type"),
        ({"command": STOP, "ttl_s": 0}, "ttl_s"),
        ({"command": STOP, "ttl_s": 3601}, "ttl_s"),
        ({"command": GO_TO, "instance_ids": ["*"]}, "command"),
        ({"command": STOP, "instance_ids": ["*", "i-1"]}, "instance_ids"),
        ({"command": STOP, "instance_ids": []}, "instance_ids"),
        ({"command": STOP, "instance_ids": ["i-" + "9" * 5000]}, "instance_ids.0"),
        (
            {"command": {"type": "go_to", "args": {"lat": 1, "lon": 1}, "max_drift_m": -1}},
            "command.max_drift_m",
        ),
    ],
)
async def test_bad_input_is_422_naming_the_field(
    w: World, body: dict[str, object], field: str
) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    payload = {"instance_ids": [v.instance_id], **body}
    r = await w.http.post("/client/submit_control", headers=op.headers, json=payload)
    assert r.status_code == 422, r.text
    error = r.json()["error"]
    assert error["code"] == "invalid"
    assert any(d["field"].startswith(field) for d in error["details"]), error


@pytest.mark.parametrize(
    ("command", "field"),
    [
        ({"type": "go_to", "args": {"lat": 1, "lon": 1, "speed": 0.3}}, "command.args.speed"),
        ({"type": "keep_station", "args": {"radius": 50}}, "command.args.radius"),
        ({"type": "follow_path", "args": {"waypoints": [{"lat": 1, "lon": 1}], "plann": True}},
         "command.args.plann"),
        ({"type": "stop", "args": {"now": True}}, "command.args.now"),
    ],
)  # fmt: skip
async def test_a_misspelt_argument_is_422_naming_it_not_dropped(
    w: World, command: dict[str, object], field: str
) -> None:
    """A go_to with ``speed`` for ``speed_mps`` ran at the vehicle's own speed, a
    keep_station with ``radius`` held 2 m: the argument the operator meant was dropped
    unsaid. Nothing is queued."""
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    r = await w.submit(op, [v], command)
    assert r.status_code == 422, r.text
    error = r.json()["error"]
    assert error["code"] == "invalid"
    assert [d["field"] for d in error["details"]] == [field], error
    assert "takes" in error["details"][0]["message"], error
    assert await w.poll(v) == []


@pytest.mark.parametrize(
    ("extra", "field"),
    [
        ({"ttl": 600}, "ttl"),
        ({"command": {"type": "keep_station", "args": {}, "max_drift": 5}}, "command.max_drift"),
    ],
)
async def test_a_misspelt_submit_field_is_422_naming_it_not_dropped(
    w: World, extra: dict[str, object], field: str
) -> None:
    """``ttl`` for ``ttl_s`` expired in 30 s, ``max_drift`` for ``max_drift_m`` sent the
    command with no drift guard: both answered 202."""
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    payload = {"instance_ids": [v.instance_id], "command": STOP, **extra}
    r = await w.http.post("/client/submit_control", headers=op.headers, json=payload)
    assert r.status_code == 422, r.text
    error = r.json()["error"]
    assert error["code"] == "invalid"
    assert [d["field"] for d in error["details"]] == [field], error
    assert await w.poll(v) == []


async def test_an_unknown_instance_is_404(w: World) -> None:
    op = await w.person("operator")
    r = await w.submit(op, ["i-nope"], STOP)
    assert r.status_code == 404
    assert r.json()["error"]["code"] == "not_found"


async def test_a_finished_instance_is_409_instance_finished(w: World) -> None:
    v = await w.vehicle()
    op = await w.person("operator", v)
    r = await w.http.post(
        "/upper/finish_instance", headers=v.headers, json={"instance_id": v.instance_id}
    )
    assert r.status_code == 200, r.text
    r = await w.submit(op, [v], STOP)
    assert r.status_code == 409
    assert r.json()["error"]["code"] == "instance_finished"


async def test_many_instances_all_or_nothing(w: World) -> None:
    held, free = await w.vehicle(), await w.vehicle()
    op = await w.operator_in_control(held)
    r = await w.submit(op, [held, free], GO_TO)
    assert r.status_code == 404  # op has no access to ``free`` at all: not found
    details = r.json()["error"]["details"]
    assert [d["instance_id"] for d in details] == [free.instance_id]
    assert await w.poll(held) == []  # nothing was queued on the one that would take it


async def test_one_refusal_among_many_names_which_and_why(w: World) -> None:
    a, b, c = await w.vehicle(), await w.vehicle(), await w.vehicle(capabilities=["stop"])
    op = await w.person("operator", a, b, c)
    for v in (a, c):
        assert (await w.grant(v, op.username)).status_code == 200
    r = await w.submit(op, [a, b, c], GO_TO)
    assert r.status_code == 409
    error = r.json()["error"]
    assert error["code"] == "control_not_held"
    assert [(d["instance_id"], d["code"]) for d in error["details"]] == [
        (b.instance_id, "control_not_held"),
        (c.instance_id, "capability_missing"),
    ]
    for v in (a, b, c):
        assert await w.poll(v) == []


async def test_many_instances_each_get_their_own_command(w: World) -> None:
    a, b = await w.vehicle(), await w.vehicle()
    op = await w.person("operator", a, b)
    for v in (a, b):
        await w.grant(v, op.username)
    r = await w.submit(op, [a, b], GO_TO)
    assert r.status_code == 202
    ids = {c["instance_id"]: c["command_id"] for c in r.json()["commands"]}
    assert set(ids) == {a.instance_id, b.instance_id}
    assert len(set(ids.values())) == 2
    for v in (a, b):
        assert [c["command_id"] for c in await w.poll(v)] == [ids[v.instance_id]]
    # queued, as asked, and said: two boats sent to one point meet there
    [meet] = r.json()["warnings"]
    assert meet.startswith("2 vehicles sent to one point") and "10 m of each other" in meet
    alone = await w.submit(op, [a], GO_TO)
    assert alone.json()["warnings"] == []
    w.clock.advance(30)  # neither heard from since: offline
    late = (await w.submit(op, [a], GO_TO)).json()
    assert late["commands"][0]["status"] == "queued"
    [waits] = late["warnings"]
    assert "is offline" in waits and "expires if it is not back" in waits


async def test_one_path_for_several_vehicles_is_said_with_advice_that_works(w: World) -> None:
    """The warning said "plan it (plan: true)", and the same path planned for two vehicles
    is refused (the second's waypoints lie in the corridor kept about the first's)."""
    a, b = await w.vehicle(), await w.vehicle()
    op = await w.person("operator", a, b)
    for v in (a, b):
        await w.grant(v, op.username)
    path = {"waypoints": [{"lat": 43.94, "lon": 15.439}, {"lat": 43.941, "lon": 15.4395}]}
    r = await w.submit(op, [a, b], {"type": "follow_path", "args": path})
    assert r.status_code == 202, r.text
    [meet] = r.json()["warnings"]
    assert meet.startswith("2 vehicles sent along one path, not planned"), meet
    assert "plan it" not in meet and "give each its own waypoints" in meet, meet
    planned = {"type": "follow_path", "args": {**path, "plan": True}}
    assert (await w.submit(op, [a, b], planned)).status_code == 422  # no advice, that
    for v, lon in ((a, 15.439), (b, 15.441)):  # the advice: each its own, one at a time
        own = [{"lat": 43.94, "lon": lon}, {"lat": 43.941, "lon": lon + 0.0005}]
        r = await w.submit(op, [v], {"type": "follow_path", "args": {"waypoints": own}})
        assert r.status_code == 202 and r.json()["warnings"] == [], r.text


async def test_stop_to_star_reaches_every_vehicle_the_caller_sees(w: World) -> None:
    a, b, hidden = await w.vehicle(), await w.vehicle(), await w.vehicle()
    op = await w.person("operator", a, b)
    r = await w.submit(op, ["*"], STOP)
    assert r.status_code == 202
    assert {c["instance_id"] for c in r.json()["commands"]} == {a.instance_id, b.instance_id}
    assert [c["type"] for c in await w.poll(a)] == ["stop"]
    assert await w.poll(hidden) == []


async def test_every_submit_is_audited(w: World) -> None:
    v = await w.vehicle()
    op = await w.operator_in_control(v)
    command_id = await w.queued(op, v, GO_TO)
    r = await w.http.get(
        "/api/events", headers=ADMIN, params={"vehicle_id": v.vehicle_id, "kind": "command"}
    )
    assert r.status_code == 200, r.text
    mine = [e for e in r.json()["events"] if e["data"].get("command_id") == command_id]
    assert mine and mine[0]["actor"] == op.username
    assert mine[0]["data"]["status"] == "queued"


async def test_stops_sent_again_to_a_vehicle_out_of_reach_wait_as_one(w: World) -> None:
    """Each stop stands for the queued ones it outlasts: the vehicle, when it is back,
    is handed one stop, not every one an operator sent meanwhile."""
    v = await w.vehicle()
    op = await w.person("operator", v)
    ids = []
    for _ in range(30):
        r = await w.submit(op, [v], STOP, ttl_s=60)
        assert r.status_code == 202, r.text
        ids.append(r.json()["commands"][0]["command_id"])
    [handed] = await w.poll(v)
    assert handed["command_id"] == ids[-1] and handed["type"] == "stop"
    first = await w.command(ids[0])
    assert first["status"] == "cancelled"
    assert first["history"][-1]["detail"] == "superseded_by_stop"
    longer = (await w.submit(op, [v], STOP, ttl_s=600)).json()["commands"][0]["command_id"]
    await w.submit(op, [v], STOP, ttl_s=5)  # would not outlast it: both wait
    assert (await w.command(longer))["status"] == "queued"
