"""Section (a) of ``bench/wan.py``: the seed's Table 2, each method paired with a bare
round trip through the WAN proxy (the module ``bench.wan`` describes the method)."""

from __future__ import annotations

import statistics
import time
from datetime import UTC, datetime
from typing import Any

import httpx

from bench import Metric
from bench._live.clients import ok
from bench._live.config import ADMIN

#: The cloud-based paper's Table 2, average delay in ms.
PAPER_MS = {
    "connect_instance": 37,
    "get_param": 104,
    "submit_control": 31,
    "update_param": 127,
    "get_control": 29,
}
OVER_RTT_MS = 3.0
CALLS, WARMUP = 50, 10


def _paired_ms(client: httpx.Client, call: Any, after: Any = None) -> tuple[float, float]:
    """Medians of ``CALLS`` timed ``call()`` and as many ``GET /healthz`` on the same
    connection, alternated so that both see the same moments of a noisy machine
    (``WARMUP`` pairs first, not counted); ``after(answer)`` runs untimed."""
    calls, bare = [], []
    for i in range(WARMUP + CALLS):
        t = time.perf_counter()
        ok(client.get("/healthz"))
        t1 = time.perf_counter()
        answer = call()
        t2 = time.perf_counter()
        if i >= WARMUP:
            bare.append((t1 - t) * 1000)
            calls.append((t2 - t1) * 1000)
        if after is not None:
            after(answer)
    return statistics.median(calls), statistics.median(bare)


def _table2_run(base: str, wan: str, run: int) -> dict[str, tuple[float, float]]:
    """One run: for each seed method, (its median, the paired baseline's), ms."""
    vid, user = f"wan-t2-{run}", f"wan-op-{run}"
    with httpx.Client(base_url=base, headers={"Authorization": f"Bearer {ADMIN}"}) as admin:
        vtoken = ok(
            admin.post(
                "/api/vehicles", json={"vehicle_id": vid, "name": vid, "vehicle_type": "usv"}
            )
        ).json()["token"]
        otoken = ok(
            admin.post("/api/users", json={"username": user, "role": "operator", "vehicles": [vid]})
        ).json()["token"]
        with httpx.Client(base_url=base, headers={"Authorization": f"Bearer {vtoken}"}) as v:
            iid = ok(
                v.post(
                    "/upper/start_instance",
                    json={"vehicle_id": vid, "capabilities": ["stop", "go_to"]},
                )
            ).json()["instance_id"]
        ok(
            admin.post(
                "/client/grant_control",
                json={"instance_id": iid, "user": user, "duration_s": 3600},
            )
        )
    seq = 0

    def update() -> None:
        nonlocal seq
        seq += 1
        sample = {
            "seq": seq,
            "ts": datetime.now(UTC).isoformat(),
            "lat": 43.94 + 1e-6 * seq,
            "lon": 15.44,
            "speed_mps": 0.4,
            "heading_deg": 90.0,
            "battery_pct": 80.0,
        }
        body = {"instance_id": iid, "params": {"mode": "auto", "seq": seq}, "samples": [sample]}
        ok(vehicle.post("/upper/update_param", json=body))

    submit = {
        "instance_ids": [iid],
        "command": {"type": "go_to", "args": {"lat": 43.95, "lon": 15.45}},
        "ttl_s": 600,
    }
    out: dict[str, tuple[float, float]] = {}
    with (
        httpx.Client(base_url=wan, headers={"Authorization": f"Bearer {otoken}"}) as op,
        httpx.Client(base_url=wan, headers={"Authorization": f"Bearer {vtoken}"}) as vehicle,
    ):
        out["connect_instance"] = _paired_ms(
            op, lambda: ok(op.post("/client/connect_instance", json={"vehicle_id": vid}))
        )
        out["update_param"] = _paired_ms(vehicle, update)
        out["get_param"] = _paired_ms(
            op, lambda: ok(op.get("/client/get_param", params={"instance_id": iid}))
        )
        out["get_control"] = _paired_ms(
            vehicle,
            lambda: ok(vehicle.get("/upper/get_control", params={"instance_id": iid, "wait_s": 0})),
        )

        def done(answer: httpx.Response) -> None:
            """The vehicle carries the command out, as the paper's did: without it every
            submit finds one more unacknowledged command on the instance to read back."""
            acks = [
                {"command_id": c["command_id"], "status": "done"} for c in answer.json()["commands"]
            ]
            body = {"instance_id": iid, "control_mode": "remote", "acks": acks}
            ok(vehicle.post("/upper/update_fbmessage", json=body))

        out["submit_control"] = _paired_ms(
            op, lambda: ok(op.post("/client/submit_control", json=submit)), done
        )
    return out


def table2(base: str, wan: str, runs: int) -> list[Metric]:
    rtt = Metric("baseline: GET /healthz through the proxy", "ms")
    absolute = {m: Metric(f"{m} (paper {ms} ms)", "ms") for m, ms in PAPER_MS.items()}
    over = {m: Metric(f"{m} over RTT", "ms", goal=("max", OVER_RTT_MS)) for m in PAPER_MS}
    for run in range(runs):
        got = _table2_run(base, wan, run)
        rtt.values.append(statistics.median(bare for _, bare in got.values()))
        for method in PAPER_MS:
            median, bare = got[method]
            absolute[method].values.append(median)
            over[method].values.append(median - bare)
    return [rtt, *absolute.values(), *over.values()]
