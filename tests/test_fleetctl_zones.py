"""``fleetctl zones`` and ``obstacles`` against a real server: a zone edited and removed
by its name, fixed obstacles listed, added and removed, names that do not resolve."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import pytest

from server.settings import Settings
from tests.factories import ADMIN, ADMIN_TOKEN, make_user, make_vehicle
from tests.fleetctl_run import fleetctl, token_of
from tests.live import serve

pytestmark = pytest.mark.usefixtures("store_backend")


def _square(path: Path, lon: float, lat: float, side: float = 0.01) -> str:
    ring = [[lon, lat], [lon + side, lat], [lon + side, lat + side], [lon, lat + side]]
    path.write_text(json.dumps({"type": "Polygon", "coordinates": [[*ring, ring[0]]]}))
    return str(path)


async def test_a_zone_is_edited_and_removed_by_its_name(
    make_settings: Callable[..., Settings], tmp_path: Path
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, _ = await make_vehicle(c)  # named vid.upper()
        reef = _square(tmp_path / "reef.json", 15.40, 43.90)
        added = await fleetctl(base, ADMIN_TOKEN, "zones", "add", "Old Reef", reef, "--json")
        assert added.exit_code == 0, added.output
        zone_id = json.loads(added.stdout)["zone_id"]

        bigger = _square(tmp_path / "bigger.json", 15.40, 43.90, side=0.02)
        edited = await fleetctl(
            base, ADMIN_TOKEN, "zones", "edit", "old reef", "--name", "reef",
            "--polygon", bigger, "--vehicle", vid.upper(), "--clearance", "25", "--json",
        )  # fmt: skip
        assert edited.exit_code == 0, edited.output
        zone = json.loads(edited.stdout)
        assert zone["zone_id"] == zone_id and zone["name"] == "reef"
        assert zone["vehicles"] == [vid] and zone["clearance_m"] == 25
        assert zone["polygon"]["coordinates"][0][2] == [15.42, 43.92]
        everyone = await fleetctl(base, ADMIN_TOKEN, "zones", "edit", "reef", "--every-vehicle")
        assert everyone.exit_code == 0, everyone.output
        stored = (await c.get("/api/zones", headers=ADMIN)).json()["zones"]
        assert stored[0]["vehicles"] == [] and stored[0]["name"] == "reef"

        nothing = await fleetctl(base, ADMIN_TOKEN, "zones", "edit", "reef")
        assert nothing.exit_code == 2 and "nothing to change" in nothing.stderr
        kind_kept = await fleetctl(base, ADMIN_TOKEN, "zones", "edit", "nowhere", "--name", "x")
        assert kind_kept.exit_code == 1 and "no zone with the id or name 'nowhere'" in (
            kind_kept.stderr
        )
        removed = await fleetctl(base, ADMIN_TOKEN, "zones", "remove", "REEF")
        assert removed.exit_code == 0, removed.output
        assert removed.stdout.strip() == f"{zone_id} (reef) removed"
        assert (await c.get("/api/zones", headers=ADMIN)).json()["zones"] == []

        # the zones as they were: the reef before it was removed, nothing before it was drawn
        then = await fleetctl(base, ADMIN_TOKEN, "zones", "--at", zone["updated_at"], "--json")
        assert then.exit_code == 0, then.output
        [past] = json.loads(then.stdout)["zones"]
        assert past["zone_id"] == zone_id and past["name"] == "reef"
        table = await fleetctl(base, ADMIN_TOKEN, "zones", "--at", zone["updated_at"])
        assert table.exit_code == 0 and "reef" in table.stdout and "as at 20" in table.stdout
        before = await fleetctl(base, ADMIN_TOKEN, "zones", "--at", "2000-01-01", "--json")
        assert before.exit_code == 0 and json.loads(before.stdout)["zones"] == []
        bad = await fleetctl(base, ADMIN_TOKEN, "zones", "--at", "yesterday")
        assert bad.exit_code == 2 and "yesterday" in bad.stderr, bad.output


async def test_two_zones_of_one_name_are_named_by_id(
    make_settings: Callable[..., Settings], tmp_path: Path
) -> None:
    async with serve(make_settings()) as base:
        shape = _square(tmp_path / "a.json", 15.40, 43.90)
        ids = []
        for _ in range(2):
            added = await fleetctl(base, ADMIN_TOKEN, "zones", "add", "pier", shape, "--json")
            ids.append(json.loads(added.stdout)["zone_id"])
        both = await fleetctl(base, ADMIN_TOKEN, "zones", "remove", "pier")
        assert both.exit_code == 2 and "2 zones are named 'pier'" in both.stderr
        assert all(i in both.stderr for i in ids)
        one = await fleetctl(base, ADMIN_TOKEN, "zones", "remove", ids[0])
        assert one.exit_code == 0, one.output


async def test_obstacles_listed_added_and_removed(
    make_settings: Callable[..., Settings], tmp_path: Path
) -> None:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        vid, _ = await make_vehicle(c)
        _, operator = await make_user(c, "operator", [vid])
        rock = _square(tmp_path / "rock.json", 15.43, 43.93, side=0.001)
        added = await fleetctl(
            base, ADMIN_TOKEN, "obstacles", "add", "rock", rock, "--clearance", "12", "--json"
        )
        assert added.exit_code == 0, added.output
        obstacle = json.loads(added.stdout)
        assert obstacle["name"] == "rock" and obstacle["clearance_m"] == 12

        listed = await fleetctl(base, token_of(operator), "obstacles")
        assert listed.exit_code == 0, listed.output
        assert obstacle["obstacle_id"] in listed.stdout and "rock" in listed.stdout
        as_json = await fleetctl(base, token_of(operator), "obstacles", "--json")
        assert json.loads(as_json.stdout)["obstacles"][0]["obstacle_id"] == obstacle["obstacle_id"]

        refused = await fleetctl(base, token_of(operator), "obstacles", "add", "x", rock)
        assert refused.exit_code == 1 and "403" in refused.stderr
        unreadable = await fleetctl(base, ADMIN_TOKEN, "obstacles", "add", "x", "/nonexistent")
        assert unreadable.exit_code == 2 and "cannot read /nonexistent" in unreadable.stderr

        removed = await fleetctl(base, ADMIN_TOKEN, "obstacles", "remove", "Rock")
        assert removed.exit_code == 0, removed.output
        assert (await c.get("/api/obstacles", headers=ADMIN)).json()["obstacles"] == []
        gone = await fleetctl(base, ADMIN_TOKEN, "obstacles", "remove", "rock")
        assert gone.exit_code == 1 and "no obstacle with the id or name 'rock'" in gone.stderr

        # the obstacles there were: the rock when it stood, with when it was removed
        then = await fleetctl(
            base, token_of(operator), "obstacles", "--at", obstacle["created_at"], "--json"
        )
        assert then.exit_code == 0, then.output
        [past] = json.loads(then.stdout)["obstacles"]
        assert past["obstacle_id"] == obstacle["obstacle_id"] and past["deleted_at"]
        table = await fleetctl(
            base, token_of(operator), "obstacles", "--at", obstacle["created_at"]
        )
        assert table.exit_code == 0 and "rock" in table.stdout and "as at 20" in table.stdout
        before = await fleetctl(base, ADMIN_TOKEN, "obstacles", "--at", "2000-01-01", "--json")
        assert before.exit_code == 0 and json.loads(before.stdout)["obstacles"] == []
        bad = await fleetctl(base, ADMIN_TOKEN, "obstacles", "--at", "yesterday")
        assert bad.exit_code == 2 and "yesterday" in bad.stderr, bad.output


async def test_a_feature_collection_of_one_polygon_draws_a_zone_and_others_are_refused(
    make_settings: Callable[..., Settings], tmp_path: Path
) -> None:
    """A FeatureCollection (what most tools export) holding one Polygon feature is taken;
    one of several features, or none, or a file with no Polygon, is refused by fleetctl
    saying what to give, exit 2, nothing sent (it was the server's 422 on
    ``polygon.type``)."""
    ring = [[15.40, 43.90], [15.41, 43.90], [15.41, 43.91], [15.40, 43.90]]
    polygon = {"type": "Polygon", "coordinates": [ring]}
    point = {"type": "Point", "coordinates": [15.4, 43.9]}

    def collection(name: str, *geometries: dict[str, Any]) -> str:
        features = [{"type": "Feature", "properties": {}, "geometry": g} for g in geometries]
        path = tmp_path / name
        path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
        return str(path)

    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base) as c:
        one = collection("one.geojson", polygon)
        added = await fleetctl(base, ADMIN_TOKEN, "zones", "add", "pier2", one, "--json")
        assert added.exit_code == 0, added.output
        assert json.loads(added.stdout)["polygon"] == polygon
        rock = await fleetctl(base, ADMIN_TOKEN, "obstacles", "add", "rock", one, "--json")
        assert rock.exit_code == 0 and json.loads(rock.stdout)["polygon"] == polygon, rock.output

        two = collection("two.geojson", polygon, polygon)
        several = await fleetctl(base, ADMIN_TOKEN, "zones", "add", "pier3", two)
        assert several.exit_code == 2, several.output
        assert f"{two} holds a FeatureCollection of 2 features (2 Polygon)" in several.stderr
        assert "exactly one such Feature" in several.stderr
        empty = collection("none.geojson")
        none = await fleetctl(base, ADMIN_TOKEN, "zones", "edit", "pier2", "--polygon", empty)
        assert none.exit_code == 2, none.output
        assert "a FeatureCollection of 0 features: a zone or an obstacle is one Polygon" in (
            none.stderr
        )
        mixed = collection("mixed.geojson", point)
        pointed = await fleetctl(base, ADMIN_TOKEN, "obstacles", "add", "buoy", mixed)
        assert pointed.exit_code == 2 and "1 feature (1 Point)" in pointed.stderr, pointed.output
        feature = tmp_path / "point.geojson"
        feature.write_text(json.dumps({"type": "Feature", "geometry": point}))
        a_point = await fleetctl(base, ADMIN_TOKEN, "zones", "add", "buoy", str(feature))
        assert a_point.exit_code == 2 and "holds a Point, not a Polygon" in a_point.stderr

        zones = (await c.get("/api/zones", headers=ADMIN)).json()["zones"]
        assert [(z["name"], z["polygon"]) for z in zones] == [("pier2", polygon)]  # unchanged
        obstacles = (await c.get("/api/obstacles", headers=ADMIN)).json()["obstacles"]
        assert [o["name"] for o in obstacles] == ["rock"]
