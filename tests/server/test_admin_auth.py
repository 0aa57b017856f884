"""Administration and authentication through HTTP."""

from __future__ import annotations

import json

import httpx
import pytest

from fleet_protocol.common import ID_RULE
from tests.factories import ADMIN, bearer, make_user, make_vehicle, start_instance

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")


async def test_no_token_is_401_in_the_envelope(client: httpx.AsyncClient) -> None:
    r = await client.get("/api/vehicles")
    assert r.status_code == 401
    assert r.json()["error"]["code"] == "unauthorized"


async def test_bad_token_is_401(client: httpx.AsyncClient) -> None:
    r = await client.get("/api/vehicles", headers=bearer("fct_not-a-token"))
    assert r.status_code == 401


async def test_admin_creates_vehicle_and_token_is_shown_once(client: httpx.AsyncClient) -> None:
    r = await client.post(
        "/api/vehicles",
        headers=ADMIN,
        json={"vehicle_id": "usv-a", "name": "A", "vehicle_type": "usv"},
    )
    assert r.status_code == 201
    body = r.json()
    assert body["vehicle_id"] == "usv-a" and body["token"].startswith("fct_")
    again = await client.post(
        "/api/vehicles",
        headers=ADMIN,
        json={"vehicle_id": "usv-a", "name": "A", "vehicle_type": "usv"},
    )
    assert again.status_code == 409
    listed = await client.get("/api/vehicles", headers=ADMIN)
    assert "token" not in listed.text


async def test_non_admin_cannot_administer(client: httpx.AsyncClient) -> None:
    _, op = await make_user(client, "operator")
    r = await client.post(
        "/api/vehicles",
        headers=op,
        json={"vehicle_id": "usv-b", "name": "B", "vehicle_type": "usv"},
    )
    assert r.status_code == 403
    assert r.json()["error"]["code"] == "forbidden"
    assert (await client.get("/api/users", headers=op)).status_code == 403


async def test_vehicle_token_cannot_use_user_routes(client: httpx.AsyncClient) -> None:
    _, vh = await make_vehicle(client)
    assert (await client.get("/api/vehicles", headers=vh)).status_code == 403


async def test_user_token_cannot_use_vehicle_routes(client: httpx.AsyncClient) -> None:
    vid, _ = await make_vehicle(client)
    r = await client.post("/upper/start_instance", headers=ADMIN, json={"vehicle_id": vid})
    assert r.status_code == 403


async def test_rotating_a_vehicle_token_revokes_the_old_one(client: httpx.AsyncClient) -> None:
    vid, old = await make_vehicle(client)
    await start_instance(client, vid, old)
    r = await client.post(f"/api/vehicles/{vid}/rotate_token", headers=ADMIN)
    assert r.status_code == 200
    new = bearer(r.json()["token"])
    assert (
        await client.post("/upper/start_instance", headers=old, json={"vehicle_id": vid})
    ).status_code == 401
    assert (
        await client.post("/upper/start_instance", headers=new, json={"vehicle_id": vid})
    ).status_code == 200


async def test_users_listed_and_disabled(client: httpx.AsyncClient) -> None:
    vid, _ = await make_vehicle(client)
    name, token = await make_user(client, "viewer", [vid])
    users = (await client.get("/api/users", headers=ADMIN)).json()["users"]
    mine = next(u for u in users if u["username"] == name)
    assert mine == {
        "username": name,
        "role": "viewer",
        "vehicles": [vid],
        "disabled": False,
        "created_at": mine["created_at"],
    }
    assert "password_hash" not in str(users)
    assert (await client.get("/api/vehicles", headers=token)).status_code == 200
    r = await client.patch(f"/api/users/{name}", headers=ADMIN, json={"disabled": True})
    assert r.status_code == 200 and r.json()["disabled"] is True
    assert (await client.get("/api/vehicles", headers=token)).status_code == 401


async def test_a_patch_of_a_user_with_a_field_it_does_not_have_changes_nothing_and_says_why(
    client: httpx.AsyncClient,
) -> None:
    """``disabld`` must not pass as a change made; the 422 names it and says why the body
    refuses it, where other bodies ignore unknown fields (docs/api.md, Conventions)."""
    name, _ = await make_user(client, "viewer", [])
    typo = {"role": "operator", "disabld": True}
    r = await client.patch(f"/api/users/{name}", headers=ADMIN, json=typo)
    assert r.status_code == 422, r.text
    [detail] = r.json()["error"]["details"]
    assert detail["field"] == "disabld", detail
    assert detail["message"].startswith("not a field of this body"), detail
    users = (await client.get("/api/users", headers=ADMIN)).json()["users"]
    assert next(u for u in users if u["username"] == name)["role"] == "viewer"


async def test_a_bad_username_or_vehicle_id_is_refused_in_words_not_by_its_pattern(
    client: httpx.AsyncClient,
) -> None:
    for path, body, field in (
        ("/api/users", {"username": "Bad Name", "role": "viewer"}, "username"),
        ("/api/vehicles", {"vehicle_id": "USV 1", "name": "x"}, "vehicle_id"),
    ):
        r = await client.post(path, headers=ADMIN, json=body)
        assert r.status_code == 422, r.text
        [detail] = r.json()["error"]["details"]
        assert detail["field"] == field, detail
        assert detail["message"] == f"an id or a name is {ID_RULE}", detail


async def test_patch_user_changes_access_at_once(client: httpx.AsyncClient) -> None:
    v1, _ = await make_vehicle(client)
    v2, _ = await make_vehicle(client)
    name, token = await make_user(client, "viewer", [v1])
    seen = [
        v["vehicle_id"]
        for v in (await client.get("/api/vehicles", headers=token)).json()["vehicles"]
    ]
    assert seen == [v1]
    await client.patch(f"/api/users/{name}", headers=ADMIN, json={"vehicles": [v2]})
    seen = [
        v["vehicle_id"]
        for v in (await client.get("/api/vehicles", headers=token)).json()["vehicles"]
    ]
    assert seen == [v2]


async def test_user_with_unknown_vehicle_is_422(client: httpx.AsyncClient) -> None:
    r = await client.post(
        "/api/users", headers=ADMIN, json={"username": "x1", "role": "viewer", "vehicles": ["nope"]}
    )
    assert r.status_code == 422
    assert r.json()["error"]["details"][0]["field"] == "vehicles"


async def test_password_login(client: httpx.AsyncClient) -> None:
    name, _ = await make_user(client, "operator", password="correct horse battery")
    r = await client.post(
        "/auth/token", json={"username": name, "password": "correct horse battery"}
    )
    assert r.status_code == 200
    body = r.json()
    assert body["token_type"] == "bearer" and body["expires_in"] > 0
    assert (
        await client.get("/api/vehicles", headers=bearer(body["access_token"]))
    ).status_code == 200
    wrong = await client.post("/auth/token", json={"username": name, "password": "nope-nope"})
    assert wrong.status_code == 401


async def test_user_token_rotation(client: httpx.AsyncClient) -> None:
    name, old = await make_user(client, "viewer")
    r = await client.post(f"/api/users/{name}/rotate_token", headers=ADMIN)
    assert r.status_code == 200
    assert (await client.get("/api/vehicles", headers=old)).status_code == 401
    assert (await client.get("/api/vehicles", headers=bearer(r.json()["token"]))).status_code == 200


async def test_gateway_acts_for_its_vehicles_only(client: httpx.AsyncClient) -> None:
    v1, _ = await make_vehicle(client)
    v2, _ = await make_vehicle(client)
    r = await client.post(
        "/api/gateways", headers=ADMIN, json={"gateway_id": "gw-1", "vehicles": [v1]}
    )
    assert r.status_code == 201
    gw = bearer(r.json()["token"])
    assert (
        await client.post("/upper/start_instance", headers=gw, json={"vehicle_id": v1})
    ).status_code == 200
    assert (
        await client.post("/upper/start_instance", headers=gw, json={"vehicle_id": v2})
    ).status_code == 403


async def test_password_login_as_a_form_too(client: httpx.AsyncClient) -> None:
    name, _ = await make_user(client, "viewer", password="correct horse battery")
    r = await client.post(
        "/auth/token", data={"username": name, "password": "correct horse battery"}
    )
    assert r.status_code == 200 and r.json()["token_type"] == "bearer"
    missing = await client.post("/auth/token", json={"username": name})
    assert missing.status_code == 422
    assert missing.json()["error"]["details"][0]["field"] == "password"


async def test_a_login_body_is_read_as_every_other_route_reads_its_body(
    client: httpx.AsyncClient,
) -> None:
    """A byte-order mark before the JSON, or a lone surrogate in a string, was "the body is
    not valid JSON" here alone: every other route reads past the mark and names the field."""
    name, _ = await make_user(client, "viewer", password="correct horse battery")
    json_type = {"Content-Type": "application/json"}
    body = json.dumps({"username": name, "password": "correct horse battery"})
    marked = await client.post(
        "/auth/token", content=b"\xef\xbb\xbf" + body.encode(), headers=json_type
    )
    assert marked.status_code == 200, marked.text
    lone = json.dumps({"username": name, "password": "?"}).replace("?", "\\ud800")
    r = await client.post("/auth/token", content=lone, headers=json_type)
    assert r.status_code == 422, r.text
    assert r.json()["error"]["details"][0]["field"] == "password", r.text
    r = await client.post("/auth/token", content="{not json", headers=json_type)
    assert r.status_code == 422 and r.json()["error"]["details"][0]["field"] == "body", r.text


async def test_admin_token_from_the_environment_survives_revocation_and_restart(
    make_settings: object,
) -> None:
    from asgi_lifespan import LifespanManager

    from server.app import create_app

    settings = make_settings()  # type: ignore[operator]
    for _ in range(2):
        app = create_app(settings)
        async with (
            LifespanManager(app) as m,
            httpx.AsyncClient(transport=httpx.ASGITransport(app=m.app), base_url="http://t") as c,
        ):
            assert (await c.get("/api/users", headers=ADMIN)).status_code == 200
            r = await c.post("/api/users/admin/revoke_tokens", headers=ADMIN)
            assert r.status_code == 200
            assert (await c.get("/api/users", headers=ADMIN)).status_code == 401


async def test_the_last_enabled_admin_cannot_be_demoted_or_disabled(
    client: httpx.AsyncClient,
) -> None:
    for change in ({"role": "viewer"}, {"disabled": True}):
        r = await client.patch("/api/users/admin", headers=ADMIN, json=change)
        assert r.status_code == 409, r.text
        assert r.json()["error"]["code"] == "last_admin"
    assert (await client.get("/api/users/admin", headers=ADMIN)).json()["role"] == "admin"
    # With a second admin, the first may step down; the second is then the last one.
    second, second_headers = await make_user(client, "admin")
    r = await client.patch("/api/users/admin", headers=ADMIN, json={"role": "operator"})
    assert r.status_code == 200 and r.json()["role"] == "operator"
    r = await client.patch(f"/api/users/{second}", headers=second_headers, json={"disabled": True})
    assert r.status_code == 409
    r = await client.patch("/api/users/admin", headers=second_headers, json={"role": "admin"})
    assert r.status_code == 200


async def test_a_store_left_without_an_admin_gets_its_admin_back_at_start(
    make_settings: object,
) -> None:
    """A store in which the last admin was disabled (as an older version allowed): the
    next start makes the bootstrap admin an enabled admin again."""
    from asgi_lifespan import LifespanManager

    from server.app import create_app

    settings = make_settings()  # type: ignore[operator]
    app = create_app(settings)
    async with LifespanManager(app):
        accounts = app.state.services.auth.repo
        await accounts.update_user("admin", {"role": "viewer", "disabled": True})
    app = create_app(settings)
    async with (
        LifespanManager(app) as m,
        httpx.AsyncClient(transport=httpx.ASGITransport(app=m.app), base_url="http://t") as c,
    ):
        r = await c.get("/api/users/admin", headers=ADMIN)
        assert r.status_code == 200
        assert r.json()["role"] == "admin" and r.json()["disabled"] is False


async def test_a_password_set_has_at_least_8_characters(client: httpx.AsyncClient) -> None:
    r = await client.post(
        "/api/users",
        headers=ADMIN,
        json={"username": "pw-short", "role": "viewer", "password": "x"},
    )
    assert r.status_code == 422 and r.json()["error"]["details"][0]["field"] == "password"
    name, _ = await make_user(client, "viewer", password="eight-ch")
    r = await client.patch(f"/api/users/{name}", headers=ADMIN, json={"password": "short"})
    assert r.status_code == 422 and r.json()["error"]["details"][0]["field"] == "password"


async def test_a_misspelt_field_of_a_user_patch_is_422_naming_it(
    client: httpx.AsyncClient,
) -> None:
    """Not a 200 that changed nothing: an admin who meant to disable someone must know."""
    name, _ = await make_user(client, "operator")
    r = await client.patch(f"/api/users/{name}", headers=ADMIN, json={"disabld": True})
    assert r.status_code == 422, r.text
    assert [d["field"] for d in r.json()["error"]["details"]] == ["disabld"]
    r = await client.patch(f"/api/users/{name}", headers=ADMIN, json={"role": "admin", "x": 1})
    assert r.status_code == 422
    assert (await client.get(f"/api/users/{name}", headers=ADMIN)).json()["role"] == "operator"


async def test_a_null_in_a_patch_is_422_naming_it_not_a_change_not_made(
    client: httpx.AsyncClient,
) -> None:
    """Left out, a field keeps its value; null kept it too, and a client meaning "none"
    (no vehicles, not disabled) took a 200 for a change made."""
    vid, _ = await make_vehicle(client)
    name, _ = await make_user(client, "operator", [vid])
    for url, body in (
        (f"/api/users/{name}", {"disabled": None}),
        (f"/api/users/{name}", {"vehicles": None}),
        (f"/api/vehicles/{vid}", {"vehicle_type": None}),
    ):
        r = await client.patch(url, headers=ADMIN, json=body)
        assert r.status_code == 422, (body, r.text)
        [detail] = r.json()["error"]["details"]
        assert detail["field"] == next(iter(body)) and "leave the field out" in detail["message"]
    assert (await client.get(f"/api/users/{name}", headers=ADMIN)).json()["vehicles"] == [vid]


async def test_a_vehicle_id_shaped_like_an_instance_id_is_refused(
    client: httpx.AsyncClient,
) -> None:
    """It would hide the instance wherever a vehicle or an instance may be named."""
    for vehicle_id in ("i-b84740e66ecaca9c", "c-0123456789abcdef"):
        body = {"vehicle_id": vehicle_id, "name": "x", "vehicle_type": "usv"}
        r = await client.post("/api/vehicles", headers=ADMIN, json=body)
        assert r.status_code == 422, r.text
        assert r.json()["error"]["details"][0]["field"] == "vehicle_id"
    body = {"vehicle_id": "i-boat", "name": "x", "vehicle_type": "usv"}  # not the shape
    assert (await client.post("/api/vehicles", headers=ADMIN, json=body)).status_code == 201


async def test_no_user_may_be_named_system_the_name_of_the_server_s_own_commands(
    client: httpx.AsyncClient,
) -> None:
    """``issued_by: "system"`` and the actor ``system`` mark what the server does on its own
    (the hold after a lease ends, a failsafe on a breach); a user of that name would pass
    for the server there, and the end of its lease would cancel the server's commands."""
    body = {"username": "system", "role": "operator", "vehicles": []}
    r = await client.post("/api/users", headers=ADMIN, json=body)
    assert r.status_code == 422, r.text
    assert r.json()["error"]["details"][0]["field"] == "username"
    body["username"] = "system-2"  # only the name itself
    assert (await client.post("/api/users", headers=ADMIN, json=body)).status_code == 201
