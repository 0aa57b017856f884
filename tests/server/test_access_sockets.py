"""Who may do what over the sockets: every op of ``/ws/vehicle`` and ``/ws/client``, and
opening each socket at all, against every kind of caller (``access_world.py``), with the
answer expected in each cell.

The rows are checked against the wire models' op unions: an op added later without a row
here fails this test. Each cell runs in a world of its own (fresh ids).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any, get_args

import httpx
import pytest
import websockets

from fleet_protocol import ClientOp, VehicleOp
from server.app import create_app
from server.settings import Settings
from tests.factories import ADMIN_TOKEN, sample
from tests.live import recv_until, serve, ws_url
from tests.server.access_world import CALLERS, World, build


#: Every op of /ws/vehicle and /ws/client: what it is sent as, per socket.
def op_names(union: Any) -> set[str]:
    """The ``op`` of every model in a (nested, annotated) union of the wire models."""
    if isinstance(union, type) and "op" in getattr(union, "model_fields", {}):
        return {union.model_fields["op"].default}
    return set().union(*(op_names(arg) for arg in get_args(union) if not _is_field(arg)))


def _is_field(arg: Any) -> bool:
    return type(arg).__name__ == "FieldInfo"


VEHICLE_OPS = op_names(VehicleOp)
CLIENT_OPS = op_names(ClientOp)

#: op -> (the frame in a world, the answer per caller: "ok" or an error code). Callers
#: that cannot open the socket at all are in SOCKET_REFUSALS.
VEHICLE_ROWS: dict[str, tuple[Callable[[World], dict[str, Any]], dict[str, str]]] = {
    "start_instance": (
        lambda w: {"vehicle_id": w.vid},
        {"vehicle": "ok", "gateway": "ok", "foreign": "forbidden"},
    ),
    "heartbeat": (
        lambda w: {"instance_id": w.iid},
        {"vehicle": "ok", "gateway": "ok", "foreign": "not_found"},
    ),
    "update_param": (
        lambda w: {"instance_id": w.iid, "samples": [sample(1)]},
        {"vehicle": "ok", "gateway": "ok", "foreign": "not_found"},
    ),
    "update_fbmessage": (
        lambda w: {"instance_id": w.iid, "acks": []},
        {"vehicle": "ok", "gateway": "ok", "foreign": "not_found"},
    ),
    "finish_instance": (
        lambda w: {"instance_id": w.iid},
        {"vehicle": "ok", "gateway": "ok", "foreign": "not_found"},
    ),
    "register": (
        lambda w: {"topics": [f"vehicle/{w.vid}/depth"], "vehicle_id": w.vid},
        {"vehicle": "ok", "gateway": "ok", "foreign": "forbidden"},
    ),
    "subscribe": (
        lambda w: {"topics": [f"vehicle/{w.vid}/telemetry"]},
        {"vehicle": "ok", "gateway": "ok", "foreign": "forbidden"},
    ),
    "unsubscribe": (
        lambda w: {"topics": [f"vehicle/{w.vid}/telemetry"]},
        {"vehicle": "ok", "gateway": "ok", "foreign": "ok"},  # nothing to leave: harmless
    ),
    "unregister": (  # its own registrations only: another vehicle's unit is not its own
        lambda w: {"topics": [f"vehicle/{w.vid}/depth"], "vehicle_id": w.vid},
        {"vehicle": "ok", "gateway": "ok", "foreign": "forbidden"},
    ),
    "publish": (
        lambda w: {"topic": f"vehicle/{w.vid}/depth", "data": 1},
        {"vehicle": "ok", "gateway": "ok", "foreign": "forbidden"},
    ),
    "whoami": (lambda w: {}, {"vehicle": "ok", "gateway": "ok", "foreign": "ok"}),  # itself
    "batch": (
        lambda w: {"ops": [{"op": "heartbeat", "instance_id": w.iid}]},
        {"vehicle": "ok", "gateway": "ok", "foreign": "ok"},  # the inner op answers apart
    ),
}
CLIENT_ROWS: dict[str, tuple[Callable[[World], dict[str, Any]], dict[str, str]]] = {
    "subscribe": (
        lambda w: {"topics": ["fleet", f"vehicle/{w.vid}/telemetry"]},
        {"viewer": "ok", "operator": "ok", "manager": "ok", "admin": "ok"},
    ),
    "unsubscribe": (
        lambda w: {"topics": ["fleet"]},
        {"viewer": "ok", "operator": "ok", "manager": "ok", "admin": "ok"},
    ),
    "register": (
        lambda w: {"topics": [f"user/viewer-{w.n}/notes"]},
        {"viewer": "ok", "operator": "forbidden", "manager": "forbidden", "admin": "forbidden"},
    ),
    "unregister": (  # what the caller itself registered: nothing of anyone else's
        lambda w: {"topics": [f"user/viewer-{w.n}/notes"]},
        {"viewer": "ok", "operator": "ok", "manager": "ok", "admin": "ok"},
    ),
    "publish": (
        lambda w: {"topic": f"user/viewer-{w.n}/notes", "data": {"n": 1}},
        {"viewer": "ok", "operator": "forbidden", "manager": "forbidden", "admin": "forbidden"},
    ),
}
#: Who cannot open each socket, and the close code.
SOCKET_REFUSALS = {
    "/ws/vehicle": {
        **{c: 4401 for c in ("anon", "revoked", "expired")},
        **{c: 4403 for c in ("viewer", "operator", "manager", "admin")},
    },
    "/ws/client": {
        **{c: 4401 for c in ("anon", "revoked", "expired")},
        **{c: 4403 for c in ("vehicle", "foreign", "gateway")},
    },
}


def test_every_op_has_a_row() -> None:
    assert VEHICLE_OPS == set(VEHICLE_ROWS), "a /ws/vehicle op without a row"
    assert CLIENT_OPS == set(CLIENT_ROWS), "a /ws/client op without a row"
    for path, rows in (("/ws/vehicle", VEHICLE_ROWS), ("/ws/client", CLIENT_ROWS)):
        for op, (_, cells) in rows.items():
            assert set(cells) | set(SOCKET_REFUSALS[path]) == set(CALLERS), (path, op)


@pytest.mark.slow
async def test_each_caller_gets_what_its_socket_cell_says(
    make_settings: Callable[..., Settings],
) -> None:
    app = create_app(make_settings())
    async with serve(Settings(), app=app) as base, httpx.AsyncClient(base_url=base) as c:
        for path, rows in (("/ws/vehicle", VEHICLE_ROWS), ("/ws/client", CLIENT_ROWS)):
            for caller, code in SOCKET_REFUSALS[path].items():
                world = await build(c, app)
                async with websockets.connect(ws_url(base, path)) as ws:
                    token = world.tokens[caller]
                    if token is not None:
                        await ws.send(json.dumps({"op": "auth", "token": token}))
                    else:
                        await ws.send(json.dumps({"op": "subscribe", "topics": ["fleet"]}))
                    with pytest.raises(websockets.ConnectionClosed):
                        await recv_until(ws, lambda f: False, within_s=10)
                    assert ws.close_code == code, (path, caller)
            for op, (frame, cells) in sorted(rows.items()):
                got = {}
                for caller in cells:
                    world = await build(c, app)
                    async with websockets.connect(ws_url(base, path)) as ws:
                        auth = {"op": "auth", "id": "a", "token": world.tokens[caller]}
                        await ws.send(json.dumps(auth))
                        assert (await recv_until(ws, lambda f: f.get("id") == "a"))["ok"]
                        await ws.send(json.dumps({"op": op, "id": "x", **frame(world)}))
                        ack = await recv_until(ws, lambda f: f.get("id") == "x")
                        got[caller] = "ok" if ack["ok"] else ack["error"]["code"]
                assert got == cells, (path, op)


async def test_a_socket_asked_where_none_is_served_is_404_in_the_envelope(
    make_settings: Callable[..., Settings],
) -> None:
    """Not 403 (a refusal of the token, which a client stops for): the path is wrong."""
    async with serve(make_settings()) as base:
        for path in ("/ws/other", "/ws/client/", "/api/vehicles", "/nowhere"):
            with pytest.raises(websockets.InvalidStatus) as refused:
                async with websockets.connect(ws_url(base, path, "fct_any-token")):
                    pass
            response = refused.value.response
            assert response.status_code == 404, (path, response.status_code)
            error = json.loads(response.body)["error"]
            assert error["code"] == "not_found", path
            assert "/ws/vehicle and /ws/client" in error["message"], error
            if path == "/ws/client/":
                assert "did you mean /ws/client?" in error["message"], error


async def test_head_is_answered_wherever_get_is(make_settings: Callable[..., Settings]) -> None:
    """Monitors probe with HEAD: /healthz answered 405. HEAD is answered as GET is (the
    same status and headers, no body); a path that takes no GET still refuses it."""
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        admin = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
        for path, headers in (("/healthz", {}), ("/readyz", {}), ("/api/vehicles", admin)):
            got, head = await c.get(path, headers=headers), await c.head(path, headers=headers)
            assert head.status_code == got.status_code == 200, (path, head.status_code)
            assert head.content == b"" and head.headers["content-length"] == str(len(got.content))
            assert head.headers["content-type"] == got.headers["content-type"]
        assert (await c.head("/api/vehicles")).status_code == 401  # as GET without a token
        refused = await c.head("/upper/heartbeat")
        assert refused.status_code == 405 and refused.headers["allow"] == "POST"
