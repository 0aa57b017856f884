"""Control leases, pure: who grants, who may hold, extension, handover, submit rules."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from server.domain import arbitration as rules
from server.domain.access import Principal
from server.domain.arbitration import ControlRequest, Grantee, Lease
from server.errors import ControlNotHeld, Forbidden, Invalid, RateLimited, VehicleLocalControl

T0 = datetime(2026, 11, 22, 10, 0, 0, tzinfo=UTC)


def user(name: str, role: str, *vehicles: str) -> Principal:
    return Principal("user", name, role, frozenset(vehicles))


def lease_for(holder: str, *, seconds: float = 60) -> Lease:
    return Lease("i-1", "usv-1", holder, "boss", T0, T0 + timedelta(seconds=seconds))


def test_a_manager_of_the_vehicle_or_an_admin_grants() -> None:
    rules.check_granter(user("boss", "manager", "usv-1"), "usv-1")
    rules.check_granter(user("root", "admin"), "usv-1")
    for who in (user("boss", "manager", "usv-2"), user("op", "operator", "usv-1")):
        with pytest.raises(Forbidden):
            rules.check_granter(who, "usv-1")


@pytest.mark.parametrize(
    ("grantee", "why"),
    [
        (None, "no such user"),
        (Grantee("v", "viewer", frozenset({"usv-1"})), "viewer cannot hold"),
        (Grantee("o", "operator", frozenset({"usv-2"})), "no access"),
        (Grantee("o", "operator", frozenset({"usv-1"}), disabled=True), "disabled"),
    ],
)
def test_the_grantee_must_be_an_operator_with_access(grantee: Grantee | None, why: str) -> None:
    with pytest.raises(Invalid) as err:
        rules.check_grantee(grantee, "someone", "usv-1")
    assert why in err.value.message
    assert err.value.details[0]["field"] == "user"


def test_an_admin_grantee_needs_no_assignment() -> None:
    rules.check_grantee(Grantee("root", "admin", frozenset()), "root", "usv-1")


def test_a_first_grant_makes_a_lease() -> None:
    lease, ended = rules.grant(
        None,
        instance_id="i-1",
        vehicle_id="usv-1",
        holder="alice",
        granted_by="boss",
        now=T0,
        duration_s=60,
    )
    assert (lease.holder, lease.expires_at, ended) == ("alice", T0 + timedelta(seconds=60), None)


def test_granting_again_to_the_holder_extends_never_shortens() -> None:
    current = lease_for("alice", seconds=600)
    longer, ended = rules.grant(
        current,
        instance_id="i-1",
        vehicle_id="usv-1",
        holder="alice",
        granted_by="boss",
        now=T0 + timedelta(seconds=10),
        duration_s=3600,
    )
    assert ended is None
    assert longer.expires_at == T0 + timedelta(seconds=3610)
    shorter, _ = rules.grant(
        current,
        instance_id="i-1",
        vehicle_id="usv-1",
        holder="alice",
        granted_by="boss",
        now=T0,
        duration_s=5,
    )
    assert shorter.expires_at == current.expires_at


def test_granting_to_someone_else_ends_the_former_lease() -> None:
    current = lease_for("alice")
    lease, ended = rules.grant(
        current,
        instance_id="i-1",
        vehicle_id="usv-1",
        holder="bob",
        granted_by="boss",
        now=T0 + timedelta(seconds=1),
        duration_s=60,
    )
    assert lease.holder == "bob"
    assert ended is current


def test_an_expired_lease_is_not_ended_again_by_a_new_grant() -> None:
    current = lease_for("alice", seconds=5)
    _, ended = rules.grant(
        current,
        instance_id="i-1",
        vehicle_id="usv-1",
        holder="bob",
        granted_by="boss",
        now=T0 + timedelta(seconds=5),
        duration_s=60,
    )
    assert ended is None


def test_submit_needs_a_live_lease_held_by_the_caller() -> None:
    alice, bob = user("alice", "operator", "usv-1"), user("bob", "operator", "usv-1")
    lease = lease_for("alice", seconds=60)
    rules.check_submit(alice, command_type="go_to", lease=lease, control_mode="remote", now=T0)
    with pytest.raises(ControlNotHeld):
        rules.check_submit(bob, command_type="go_to", lease=lease, control_mode="remote", now=T0)
    with pytest.raises(ControlNotHeld):
        rules.check_submit(
            alice,
            command_type="go_to",
            lease=lease,
            control_mode="remote",
            now=T0 + timedelta(seconds=60),
        )
    with pytest.raises(ControlNotHeld):
        rules.check_submit(alice, command_type="go_to", lease=None, control_mode="idle", now=T0)


def test_stop_passes_without_a_lease_and_under_local_control() -> None:
    bob = user("bob", "operator", "usv-1")
    rules.check_submit(bob, command_type="stop", lease=None, control_mode="local", now=T0)


def test_local_control_refuses_everything_but_stop() -> None:
    alice = user("alice", "operator", "usv-1")
    with pytest.raises(VehicleLocalControl):
        rules.check_submit(
            alice, command_type="go_to", lease=lease_for("alice"), control_mode="local", now=T0
        )


def test_only_the_holder_releases() -> None:
    lease = lease_for("alice")
    assert rules.check_release(lease, user("alice", "operator"), T0) is lease
    with pytest.raises(ControlNotHeld):
        rules.check_release(lease, user("bob", "operator"), T0)


def test_control_requests_are_one_per_user_and_bounded() -> None:
    def req(name: str) -> ControlRequest:
        return ControlRequest(f"r-{name}", name, "i-1", "usv-1", T0)

    pending, first = rules.add_request([], req("a"), limit=2)
    pending, again = rules.add_request(pending, req("a"), limit=2)
    assert again is first
    assert len(pending) == 1
    pending, _ = rules.add_request(pending, req("b"), limit=2)
    with pytest.raises(RateLimited):
        rules.add_request(pending, req("c"), limit=2)
