"""A gateway's record of its topics' states (pure): which topics have one, and its bounds."""

from __future__ import annotations

from fleet_protocol.topics import KEEP_MAX_BYTES as MAX_KEPT_MESSAGE_BYTES
from vehicle_client.gateway.forwarding import LatestKept, has_state


def test_the_topics_with_a_state_are_those_the_server_keeps() -> None:
    assert has_state("vehicle/usv-1/sonar_meta")
    assert has_state("user/ana/plan/usv-1")
    assert has_state("gateway/gw-1/status")
    for server_s in ("fleet", "zones", "vehicle/usv-1/commands", "vehicle/usv-1/telemetry"):
        assert not has_state(server_s)
    assert not has_state("vehicle/usv-1/camera/front")  # media: latest wins, no state


def test_a_message_too_large_to_keep_leaves_no_state_behind_it() -> None:
    kept = LatestKept()
    kept.note("vehicle/usv-1/plan", "small", 10)
    assert kept.latest("vehicle/usv-1/plan") == "small"
    kept.note("vehicle/usv-1/plan", "large", MAX_KEPT_MESSAGE_BYTES + 1)
    assert kept.latest("vehicle/usv-1/plan") is None  # "small" is no longer the latest
    kept.note("vehicle/usv-1/commands", "list", 10)
    assert kept.latest("vehicle/usv-1/commands") is None


def test_past_its_bound_the_topics_written_longest_ago_go_first() -> None:
    kept = LatestKept(max_bytes=300)
    for n in range(3):
        kept.note(f"vehicle/usv-1/t{n}", n, 100)
    kept.note("vehicle/usv-1/t0", "again", 100)  # written again: the newest now
    kept.note("vehicle/usv-1/t3", 3, 100)
    assert kept.latest("vehicle/usv-1/t1") is None
    assert [kept.latest(f"vehicle/usv-1/t{n}") for n in (0, 2, 3)] == ["again", 2, 3]
