"""Latency per hop, measured by the server (docs/live.md, "Latency per hop"): what the
wire carries for it, the histograms on ``/metrics`` and the link delay in the views.

On the test's clock (``FakeClock``) every delay is set by hand, so the values are exact;
over real sockets only that each hop was counted is checked (speed is ``make bench``'s).
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import timedelta
from typing import Any

import httpx
import pytest
from prometheus_client.parser import text_string_to_metric_families

from fleet_protocol import format_ts, utcnow
from server.settings import Settings
from tests.factories import ADMIN, ADMIN_TOKEN, make_vehicle, sample
from tests.live import call, connect, recv_until, serve
from tests.server.commanding import GO_TO, eventually, world

# Each test runs on the embedded store and on FerretDB (the real MongoDB driver).
pytestmark = pytest.mark.usefixtures("store_backend")

SKEW = timedelta(seconds=5)  # the vehicle's clock runs 5 s ahead of the server's


def metric(text: str, name: str, **labels: str) -> float:
    """The value of one sample of ``/metrics`` (0 when it is not there)."""
    for family in text_string_to_metric_families(text):
        for s in family.samples:
            if s.name == name and all(s.labels.get(k) == v for k, v in labels.items()):
                return float(s.value)
    return 0.0


async def metrics_of(http: httpx.AsyncClient) -> str:
    r = await http.get("/metrics")
    assert r.status_code == 200
    return r.text


async def test_a_skewed_vehicle_clock_is_corrected_into_the_histogram_and_the_view(
    make_settings: Callable[..., Settings],
) -> None:
    async with world(make_settings()) as w:
        vehicle = await w.vehicle()
        # Sent 30 ms before it arrives, by a clock 5 s ahead that knows it is.
        sent_at = w.clock() + SKEW - timedelta(milliseconds=30)
        r = await w.http.post(
            "/upper/update_param",
            headers=vehicle.headers,
            json={
                "instance_id": vehicle.instance_id,
                "samples": [sample(1, ts=w.clock())],
                "sent_at": format_ts(sent_at),
                "clock_offset_s": -5.0,
                "rtt_s": 0.045,
            },
        )
        assert r.status_code == 200, r.text
        assert r.json()["accepted"] == 1
        assert r.json()["server_time"] == format_ts(w.clock())  # for the vehicle's estimate
        view = (await w.http.get(f"/api/vehicles/{vehicle.vehicle_id}", headers=ADMIN)).json()
        assert (view["link_delay_ms"], view["link_rtt_ms"]) == (30.0, 45.0)
        w.clock.advance(60)  # out of contact: its link's delay is not the link's now
        view = (await w.http.get(f"/api/vehicles/{vehicle.vehicle_id}", headers=ADMIN)).json()
        assert view["presence"] == "offline"
        assert (view["link_delay_ms"], view["link_rtt_ms"]) == (None, None)
        text = await metrics_of(w.http)
        hop = "fleet_hop_vehicle_to_server_seconds"
        assert metric(text, f"{hop}_count", transport="http") == 1
        assert metric(text, f"{hop}_bucket", transport="http", le="0.02") == 0
        assert metric(text, f"{hop}_bucket", transport="http", le="0.05") == 1
        assert metric(text, f"{hop}_sum", transport="http") == pytest.approx(0.030)


async def test_a_call_without_timing_or_with_a_wild_clock_is_served_and_not_observed(
    make_settings: Callable[..., Settings],
) -> None:
    async with world(make_settings()) as w:
        vehicle = await w.vehicle()
        plain = {"instance_id": vehicle.instance_id, "samples": [sample(1, ts=w.clock())]}
        r = await w.http.post("/upper/update_param", headers=vehicle.headers, json=plain)
        assert r.status_code == 200, r.text
        wild = {
            "instance_id": vehicle.instance_id,
            "samples": [sample(2, ts=w.clock())],
            "sent_at": format_ts(w.clock()),
            "clock_offset_s": 86_400.0,  # a day: a clock gone wrong, not a delay
        }
        r = await w.http.post("/upper/update_param", headers=vehicle.headers, json=wild)
        assert r.status_code == 200, r.text
        assert r.json()["accepted"] == 1
        behind = {**wild, "samples": [sample(3, ts=w.clock())], "clock_offset_s": 0.004}
        r = await w.http.post("/upper/update_param", headers=vehicle.headers, json=behind)
        assert r.status_code == 200, r.text  # 4 ms below zero: clocks a little apart
        text = await metrics_of(w.http)
        hop = "fleet_hop_vehicle_to_server_seconds"
        assert metric(text, f"{hop}_count", transport="http") == 1  # the clamped one, as 0
        assert metric(text, f"{hop}_sum", transport="http") == 0
        assert metric(text, "fleet_hop_discarded_total", hop="vehicle_to_server") == 1
        assert metric(text, "fleet_hop_clamped_total", hop="vehicle_to_server") == 1
        assert metric(text, "fleet_samples_ingested_total") == 3  # every sample, timed or not
        view = (await w.http.get(f"/api/vehicles/{vehicle.vehicle_id}", headers=ADMIN)).json()
        assert view["link_delay_ms"] == 0.0 and view["link_rtt_ms"] is None


async def test_a_command_is_timed_from_submission_to_hand_out_to_ack(
    make_settings: Callable[..., Settings],
) -> None:
    async with world(make_settings()) as w:
        vehicle = await w.vehicle()
        op = await w.operator_in_control(vehicle)
        command_id = await w.queued(op, vehicle, GO_TO)
        w.clock.advance(0.2)
        assert [c["command_id"] for c in await w.poll(vehicle)] == [command_id]
        w.clock.advance(0.3)
        await w.ack(vehicle, (command_id, "accepted"))
        w.clock.advance(0.1)
        await w.ack(vehicle, (command_id, "executing"))  # not a first ack: not counted
        text = await metrics_of(w.http)
        for name, seconds in (
            ("fleet_command_submitted_to_delivered_seconds", 0.2),
            ("fleet_command_delivered_to_acked_seconds", 0.3),
            ("fleet_command_submitted_to_acked_seconds", 0.5),
        ):
            assert metric(text, f"{name}_count") == 1, name
            assert metric(text, f"{name}_sum") == pytest.approx(seconds), name


async def test_over_sockets_each_hop_is_counted_and_the_fleet_topic_shows_the_delay(
    make_settings: Callable[..., Settings],
) -> None:
    async with (
        serve(make_settings()) as base,
        httpx.AsyncClient(base_url=base, timeout=10) as api,
    ):
        vid, vh = await make_vehicle(api)
        async with (
            await connect(base, "/ws/client", ADMIN_TOKEN) as operator,
            await connect(base, "/ws/vehicle", vh["Authorization"][7:]) as vehicle,
        ):
            started = await call(
                vehicle, "start_instance", "s", vehicle_id=vid, capabilities=["stop"]
            )
            assert started["ok"], started
            telemetry = f"vehicle/{vid}/telemetry"
            assert (await call(operator, "subscribe", "t", topics=[telemetry]))["ok"]
            # Ops run in order: by this ack, the telemetry stream is live (past its snapshot).
            assert (await call(operator, "subscribe", "f", topics=["fleet"]))["ok"]
            ack = await call(
                vehicle,
                "update_param",
                "u",
                instance_id=started["instance_id"],
                samples=[sample(1, ts=utcnow())],
                sent_at=format_ts(utcnow()),
                clock_offset_s=0.0,
                rtt_s=0.002,
            )
            assert ack["ok"] and ack["accepted"] == 1 and ack["server_time"], ack

            # Both changes, in whichever order they come (a snapshot may hold one back).
            delay_view: dict[str, Any] | None = None
            sample_heard = False
            while delay_view is None or not sample_heard:
                frame = await recv_until(operator, lambda f: f.get("op") == "event")
                if frame.get("snapshot"):
                    continue
                if frame["topic"] == telemetry:
                    sample_heard = True
                for view in frame["data"]["vehicles"] if frame["topic"] == "fleet" else []:
                    if view["vehicle_id"] == vid and view["link_delay_ms"] is not None:
                        delay_view = view
            assert delay_view["link_delay_ms"] >= 0 and delay_view["link_rtt_ms"] == 2.0

        # A frame is counted once its write returns, which the reader may beat.
        async def written() -> bool:
            seen = await metrics_of(api)
            return metric(seen, "fleet_hop_server_to_operator_seconds_count") >= 2

        await eventually(written)
        text = await metrics_of(api)
        assert metric(text, "fleet_hop_vehicle_to_server_seconds_count", transport="ws") == 1
        assert metric(text, "fleet_hop_discarded_total", hop="server_to_operator") == 0
