"""Topic permissions: who writes and reads which topic, and which unit an op acts as."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from server.domain.topics import (
    UnitRef,
    can_read,
    can_write,
    check_read,
    check_write,
    unit_for,
)
from server.errors import Forbidden, Invalid


@dataclass(frozen=True)
class Caller:
    kind: str
    name: str
    vehicles: frozenset[str] = field(default_factory=frozenset)
    admin: bool = False

    @property
    def is_admin(self) -> bool:
        return self.kind == "user" and self.admin

    def can_see(self, vehicle_id: str) -> bool:
        if self.kind == "vehicle":
            return vehicle_id == self.name
        return self.admin or vehicle_id in self.vehicles

    def acts_for(self, vehicle_id: str) -> bool:
        if self.kind == "vehicle":
            return vehicle_id == self.name
        return self.kind == "gateway" and vehicle_id in self.vehicles

    def reads_vehicle(self, vehicle_id: str) -> bool:
        return self.can_see(vehicle_id) or self.acts_for(vehicle_id)


def vehicle(name: str = "usv-1") -> Caller:
    return Caller("vehicle", name)


def gateway(name: str = "gw-1", *vehicles: str) -> Caller:
    return Caller("gateway", name, frozenset(vehicles or ("usv-1",)))


def user(name: str = "alice", *vehicles: str, admin: bool = False) -> Caller:
    return Caller("user", name, frozenset(vehicles), admin)


@pytest.mark.parametrize("kind", ["telemetry", "commands", "control", "events"])
@pytest.mark.parametrize("caller", [vehicle(), gateway(), user("root", admin=True)])
def test_server_only_vehicle_topics_refuse_every_writer(kind, caller):
    assert not can_write(caller, f"vehicle/usv-1/{kind}")
    assert not can_write(caller, f"vehicle/usv-1/{kind}/sub")


@pytest.mark.parametrize("caller", [vehicle(), gateway(), user(admin=True)])
def test_fleet_is_server_only(caller):
    assert not can_write(caller, "fleet")


def test_vehicle_writes_its_own_namespace_only():
    assert can_write(vehicle("usv-1"), "vehicle/usv-1/camera")
    assert can_write(vehicle("usv-1"), "vehicle/usv-1/sonar/raw")
    assert not can_write(vehicle("usv-1"), "vehicle/usv-2/camera")
    assert not can_write(vehicle("usv-1"), "user/usv-1/result")


def test_gateway_writes_for_the_vehicles_it_lists_and_its_own_namespace():
    gw = gateway("gw-1", "usv-1", "auv-2")
    assert can_write(gw, "vehicle/auv-2/depth")
    assert not can_write(gw, "vehicle/usv-9/depth")
    assert can_write(gw, "gateway/gw-1/status")
    assert not can_write(gw, "gateway/gw-2/status")


def test_user_writes_only_under_its_username():
    assert can_write(user("alice"), "user/alice/seg/mask")
    assert not can_write(user("alice"), "user/bob/seg")
    assert not can_write(user("root", admin=True), "user/alice/x")
    assert not can_write(user("alice", "usv-1"), "vehicle/usv-1/camera")


@pytest.mark.parametrize("topic", ["other/x/y", "vehicle/usv-1", "user/alice"])
def test_topics_outside_the_namespaces_or_too_short_are_not_writable(topic):
    assert not can_write(vehicle("usv-1"), topic)
    assert not can_write(user("alice"), topic)


def test_reading_a_vehicle_topic_needs_access_to_the_vehicle():
    assert can_read(user("alice", "usv-1"), "vehicle/usv-1/telemetry")
    assert not can_read(user("alice", "usv-1"), "vehicle/usv-2/telemetry")
    assert can_read(user("root", admin=True), "vehicle/usv-2/camera")
    assert can_read(vehicle("usv-1"), "vehicle/usv-1/commands")
    assert not can_read(vehicle("usv-1"), "vehicle/usv-2/camera")
    assert can_read(gateway("gw", "usv-2"), "vehicle/usv-2/camera")


def test_fleet_is_readable_by_users_only():
    assert can_read(user("viewer"), "fleet")
    assert not can_read(vehicle(), "fleet")
    assert not can_read(gateway(), "fleet")


def test_a_user_namespace_is_read_by_that_user_and_admins():
    assert can_read(user("worker"), "user/worker/seg/mask")
    assert can_read(user("root", admin=True), "user/worker/seg/mask")
    for caller in (vehicle(), gateway(), user("bob", "usv-1")):
        assert not can_read(caller, "user/worker/plan")
        assert not can_read(caller, "user/worker/seg/mask")


def test_a_users_topic_about_a_vehicle_is_read_by_the_vehicles_readers():
    """The offloading case: a worker's results about usv-1 reach usv-1 and its readers."""
    topic = "user/worker/segmentation/usv-1"
    for caller in (vehicle("usv-1"), gateway("gw", "usv-1"), user("ana", "usv-1")):
        assert can_read(caller, topic)
        assert can_read(caller, topic + "/mask")
    for caller in (vehicle("usv-2"), gateway("gw", "usv-2"), user("bob", "usv-2")):
        assert not can_read(caller, topic)


def test_a_gateway_namespace_is_read_by_it_its_units_their_readers_and_admins():
    gateways = {"gw-9": frozenset({"usv-1", "auv-2"})}
    topic = "gateway/gw-9/status"
    for caller in (
        gateway("gw-9", "usv-1"),
        vehicle("auv-2"),
        user("ana", "usv-1"),
        user("root", admin=True),
    ):
        assert can_read(caller, topic, gateways), caller
    for caller in (gateway("gw-8", "usv-3"), vehicle("usv-3"), user("bob", "usv-3"), user("eve")):
        assert not can_read(caller, topic, gateways), caller
    assert not can_read(user("ana", "usv-1"), "gateway/gw-unknown/status", gateways)


def test_checks_raise_forbidden_naming_the_topic():
    with pytest.raises(Forbidden, match="only vehicle usv-2") as caught:
        check_write(vehicle("usv-1"), ["vehicle/usv-1/camera", "vehicle/usv-2/camera"])
    assert caught.value.details == [
        {
            "field": "topics.1",
            "message": "vehicle/usv-2/camera: only vehicle usv-2 (or its gateway) writes"
            " under 'vehicle/usv-2/'",
        }
    ]
    with pytest.raises(Forbidden, match="no read access") as caught:
        check_read(user("alice"), "vehicle/usv-1/telemetry")
    assert [d["field"] for d in caught.value.details] == ["topic"]
    check_read(user("alice", "usv-1"), ["fleet", "vehicle/usv-1/telemetry"])
    check_write(user("alice"), "user/alice/x")


@pytest.mark.parametrize("topic", ["user/alice", "vehicle/usv-1", "gateway", "fleet/x", "foo/a/b"])
def test_a_topic_of_no_known_shape_is_invalid_for_everyone(topic: str) -> None:
    """The same for every caller, the admin too: a 422, not a refusal of rights."""
    for actor in (user("alice", "usv-1"), user("root", admin=True), vehicle("usv-1")):
        for check in (check_read, check_write):
            with pytest.raises(Invalid) as caught:
                check(actor, ["vehicle/usv-1/x", topic] if check is check_read else [topic])
            field = "topics.1" if check is check_read else "topics.0"
            assert [d["field"] for d in caught.value.details] == [field], (topic, actor)


def test_unit_for_each_kind_of_caller():
    assert unit_for(vehicle("usv-1")) == UnitRef("vehicle:usv-1", "vehicle")
    assert unit_for(vehicle("usv-1"), "usv-1") == UnitRef("vehicle:usv-1", "vehicle")
    assert unit_for(gateway("gw", "usv-1")) == UnitRef("gateway:gw", "gateway")
    assert unit_for(gateway("gw", "usv-1"), "usv-1") == UnitRef(
        "vehicle:usv-1", "vehicle", parent="gateway:gw"
    )
    assert unit_for(user("alice")) == UnitRef("user:alice", "operator")


@pytest.mark.parametrize(
    ("caller", "vehicle_id"),
    [(vehicle("usv-1"), "usv-2"), (gateway("gw", "usv-1"), "usv-2"), (user("a", "usv-1"), "usv-1")],
)
def test_unit_for_refuses_acting_for_another_vehicle(caller, vehicle_id):
    with pytest.raises(Forbidden):
        unit_for(caller, vehicle_id)
