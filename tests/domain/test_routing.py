"""The routing table: views, change sets, delivery, gateway forwarding, bounds."""

from __future__ import annotations

import pytest

from server.domain.routing import RoutingTable, UnitView
from server.errors import Conflict, Invalid, NotFound

CAM = "vehicle/rov-1/camera"
MASK = "user/worker/mask"


def make_table(**kwargs) -> RoutingTable:
    """A surface gateway with an underwater unit under it, a cloud worker, an operator."""
    table = RoutingTable(**kwargs)
    table.add_unit("gw", "gateway")
    table.add_unit("rov-1", "vehicle", parent="gw")
    table.add_unit("worker", "worker")
    table.add_unit("op", "operator")
    return table


def test_a_new_unit_has_an_empty_view():
    table = make_table()
    assert table.view("op") == UnitView("op")
    assert table.view("gw") == UnitView("gw")


def test_register_then_subscribe_tells_both_sides_and_the_gateway():
    table = make_table()
    assert table.register("rov-1", [CAM]) == {"rov-1"}
    assert table.subscribe("worker", [CAM]) == {"worker", "rov-1", "gw"}
    assert table.view("rov-1").produces == {CAM: ("worker",)}
    assert table.view("worker").consumes == {CAM: ("rov-1",)}
    assert table.view("gw").forward_up == (CAM,)


def test_a_second_subscriber_does_not_touch_the_first_one():
    table = make_table()
    table.register("rov-1", [CAM])
    table.subscribe("worker", [CAM])
    changed = table.subscribe("op", [CAM])
    assert "worker" not in changed
    assert changed == {"op", "rov-1"}  # gw already forwards CAM up
    assert table.view("rov-1").produces == {CAM: ("op", "worker")}


def test_repeating_a_subscription_changes_nothing():
    table = make_table()
    table.subscribe("op", [CAM])
    assert table.subscribe("op", [CAM]) == frozenset()
    assert table.unsubscribe("op", ["vehicle/rov-1/other"]) == frozenset()


def test_subscribers_are_exactly_the_subscribed_units():
    table = make_table()
    table.register("rov-1", [CAM])
    table.subscribe("worker", [CAM, MASK])
    table.subscribe("op", [MASK])
    assert table.subscribers(CAM) == {"worker"}
    assert table.subscribers(MASK) == {"worker", "op"}
    assert table.subscribers("fleet") == frozenset()
    table.unsubscribe("worker", [MASK])
    assert table.subscribers(MASK) == {"op"}
    assert table.producers(CAM) == {"rov-1"}


def test_demand_driven_forwarding_upward():
    table = make_table()
    table.add_unit("rov-2", "vehicle", parent="gw")
    table.register("rov-1", [CAM])
    assert table.forward_up("gw") == frozenset()  # nobody asked
    table.subscribe("rov-2", [CAM])
    assert table.forward_up("gw") == frozenset()  # consumed locally only
    assert table.forward_down("gw") == {CAM}
    table.subscribe("op", [CAM])
    assert table.forward_up("gw") == frozenset()  # asked upstream, but consumed below
    table.unsubscribe("rov-2", [CAM])
    assert table.forward_up("gw") == {CAM}  # someone upstream asked, nobody below
    assert table.unsubscribe("op", [CAM]) == {"op", "rov-1", "gw"}
    assert table.forward_up("gw") == frozenset()


def test_forwarding_downward_is_what_the_units_below_subscribed_to():
    table = make_table()
    table.register("worker", [MASK])
    changed = table.subscribe("rov-1", [MASK])
    assert changed == {"rov-1", "gw", "worker"}
    assert table.view("gw").forward_down == (MASK,)
    assert table.view("gw").forward_up == ()
    # The gateway's own subscriptions are its own, not forwarded down.
    table.unsubscribe("rov-1", [MASK])
    table.subscribe("gw", [MASK])
    assert table.forward_down("gw") == frozenset()


def test_recipients_are_endpoints_and_skip_the_publishers_own():
    table = make_table()
    table.add_unit("rov-2", "vehicle", parent="gw")
    table.subscribe("rov-2", [CAM])
    table.subscribe("op", [CAM])
    table.subscribe("worker", [CAM])
    # From rov-1 (under gw): gw served rov-2 locally; the cloud sends to the others.
    assert table.recipients(CAM, source="rov-1") == {"op", "worker"}
    # From the server: every endpoint with a subscriber, gw once for its units.
    assert table.recipients(CAM) == {"gw", "op", "worker"}
    # A unit never gets its own publish back.
    assert table.recipients(CAM, source="op") == {"gw", "worker"}


def test_nested_gateways_forward_through_each_layer():
    table = RoutingTable()
    table.add_unit("cloud-gw", "gateway")
    table.add_unit("surface", "gateway", parent="cloud-gw")
    table.add_unit("auv", "vehicle", parent="surface")
    table.add_unit("op", "operator")
    table.register("auv", [CAM])
    assert table.endpoint("auv") == "cloud-gw"
    changed = table.subscribe("op", [CAM])
    assert changed == {"op", "auv", "surface", "cloud-gw"}
    assert table.forward_up("surface") == {CAM}
    assert table.forward_up("cloud-gw") == {CAM}
    table.unsubscribe("op", [CAM])
    table.add_unit("boat", "vehicle", parent="cloud-gw")
    table.subscribe("boat", [CAM])
    assert table.forward_up("surface") == {CAM}  # up to cloud-gw, which serves boat
    assert table.forward_up("cloud-gw") == frozenset()  # nobody above asked


def test_remove_unit_drops_its_subtree_and_reports_the_others():
    table = make_table()
    table.register("rov-1", [CAM])
    table.subscribe("worker", [CAM])
    table.register("worker", [MASK])
    table.subscribe("rov-1", [MASK])
    changed = table.remove_unit("gw")
    assert changed == {"worker"}
    assert "rov-1" not in table
    assert table.view("worker") == UnitView("worker", {MASK: ()}, {CAM: ()})
    assert table.subscribers(MASK) == frozenset()


def test_view_as_dict_fits_the_routes_push():
    from fleet_protocol.ws import RoutesPush

    table = make_table()
    table.register("rov-1", [CAM])
    table.subscribe("op", [CAM])
    push = RoutesPush(**table.view("gw").as_dict())
    assert push.forward_up == [CAM]
    assert RoutesPush(**table.view("rov-1").as_dict()).produces == {CAM: ["op"]}


def test_topics_per_unit_are_bounded_and_refused_whole():
    table = make_table(max_topics_per_unit=3)
    table.subscribe("op", ["user/a/x", "user/a/y"])
    with pytest.raises(Invalid) as caught:
        table.subscribe("op", ["user/a/z", "user/a/w"])
    assert caught.value.code == "too_many_topics"
    assert [d["field"] for d in caught.value.details] == ["topics"]
    assert table.view("op").consumes.keys() == {"user/a/x", "user/a/y"}
    table.subscribe("op", ["user/a/z", "user/a/x"])  # one new: fits
    table.register("op", ["user/op/a", "user/op/b", "user/op/c"])  # its own bound


def test_unknown_units_and_bad_parents_are_refused():
    table = make_table()
    with pytest.raises(NotFound):
        table.subscribe("ghost", [CAM])
    with pytest.raises(NotFound):
        table.add_unit("x", "vehicle", parent="op")  # not a gateway
    with pytest.raises(Conflict):
        table.add_unit("rov-1", "vehicle")  # already under gw
    table.add_unit("rov-1", "vehicle", parent="gw")  # the same again: fine
