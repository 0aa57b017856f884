"""Property tests: the change sets are exact, forwarding follows its definition."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from server.domain.routing import RoutingTable

#: (unit, kind, parent): two layers of gateways, a second gateway, cloud units.
LAYOUT = [
    ("g1", "gateway", None),
    ("g2", "gateway", "g1"),
    ("v1", "vehicle", "g1"),
    ("v2", "vehicle", "g2"),
    ("v3", "vehicle", "g2"),
    ("g3", "gateway", None),
    ("v4", "vehicle", "g3"),
    ("w", "worker", None),
    ("o", "operator", None),
]
UNITS = [u for u, _, _ in LAYOUT]
TOPICS = [f"user/x/t{i}" for i in range(5)]

topic_ops = st.tuples(
    st.sampled_from(["register", "unregister", "subscribe", "unsubscribe"]),
    st.sampled_from(UNITS),
    st.lists(st.sampled_from(TOPICS), min_size=1, max_size=3),
)
remove_ops = st.tuples(st.just("remove"), st.sampled_from(UNITS), st.just([]))
ops = st.lists(st.one_of(topic_ops, topic_ops, topic_ops, remove_ops), max_size=40)


def build() -> RoutingTable:
    table = RoutingTable(max_topics_per_unit=len(TOPICS))
    for unit, kind, parent in LAYOUT:
        table.add_unit(unit, kind, parent)
    return table


def restore(table: RoutingTable) -> None:
    """Put back units a ``remove`` took away (parents first)."""
    for unit, kind, parent in LAYOUT:
        if unit not in table and (parent is None or parent in table):
            table.add_unit(unit, kind, parent)


def inside(table: RoutingTable, unit: str, gateway: str) -> bool:
    while unit is not None:
        if unit == gateway:
            return True
        unit = table.parent(unit)
    return False


@settings(max_examples=300, deadline=None)
@given(ops)
def test_change_sets_are_exactly_the_units_whose_view_changed(sequence):
    table = build()
    for name, unit, topics in sequence:
        restore(table)
        before = {u: table.view(u) for u in table.units()}
        if name == "remove":
            changed = table.remove_unit(unit)
        else:
            changed = getattr(table, name)(unit, topics)
        after = {u: table.view(u) for u in table.units()}
        actual = {u for u in after if before[u] != after[u]}
        assert changed == actual, (name, unit, topics)


@settings(max_examples=200, deadline=None)
@given(ops)
def test_forwarding_and_delivery_follow_their_definitions(sequence):
    table = build()
    for name, unit, topics in sequence:
        restore(table)
        if name == "remove":
            table.remove_unit(unit)
        else:
            getattr(table, name)(unit, topics)
    restore(table)
    views = {u: table.view(u) for u in table.units()}
    for topic in TOPICS:
        subscribed = {u for u, v in views.items() if topic in v.consumes}
        assert table.subscribers(topic) == subscribed
        for source in table.units():
            expected = {table.endpoint(u) for u in subscribed} - {table.endpoint(source)}
            assert table.recipients(topic, source) == expected
    for gateway in ("g1", "g2", "g3"):
        members = {u for u in views if inside(table, u, gateway)}
        up = {
            t
            for t in TOPICS
            if any(t in views[m].produces for m in members)
            and any(t in views[u].consumes for u in set(views) - members)
            and not any(t in views[m].consumes for m in members)
        }
        down = {t for m in members - {gateway} for t in views[m].consumes}
        assert set(views[gateway].forward_up) == up
        assert set(views[gateway].forward_down) == down
    for unit, view in views.items():
        for topic, consumers in view.produces.items():
            assert set(consumers) == table.subscribers(topic) - {unit}
