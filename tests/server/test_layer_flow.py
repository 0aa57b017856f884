"""One ``update_param`` followed from the vehicle's socket to the store: every call of the
server on the way goes down the layers, and enters each layer once (api -> services ->
storage), with no call back up. News the services send on (a sample for subscribers)
goes out through the message bus, where a new chain starts."""

from __future__ import annotations

import sys
from collections.abc import Callable
from types import FrameType
from typing import Any

import httpx

from server.settings import Settings
from tests.factories import ADMIN, make_vehicle
from tests.live import call, connect, serve

#: Rank of each layer the chain may enter (the leaves every layer uses are left out).
RANK = {
    "server.api": 4,
    "server.services": 3,
    "server.storage": 2,
    "server.bus": 2,
    "server.domain": 1,
}
LEAVES = ("server.errors", "server.settings", "server.metrics")
#: Where news starts a new chain: handlers registered by the composition root.
RELAYS = ("server.services.messagebus", "server.bus.base")


def layer(module: str) -> str | None:
    if module.startswith(LEAVES):
        return None
    for prefix in RANK:
        if module == prefix or module.startswith(prefix + "."):
            return prefix
    return "root"  # the composition root (container, app)


def chains_of(stacks: list[list[tuple[str, str]]]) -> list[list[str]]:
    """Each stack as the layers it entered, in order, cut where news is relayed."""
    out = []
    for stack in stacks:
        chain: list[str] = []
        for module, _function in stack:
            if module.startswith(RELAYS):
                chain = []  # what a relay calls is a new flow
                continue
            name = layer(module)
            if name is not None and (not chain or chain[-1] != name):
                chain.append(name)
        out.append(chain)
    return out


def recorder() -> tuple[list[list[tuple[str, str]]], Callable[[FrameType, str, Any], None]]:
    stacks: list[list[tuple[str, str]]] = []

    def profile(frame: FrameType, event: str, _arg: Any) -> None:
        if event != "call" or not frame.f_globals.get("__name__", "").startswith("server."):
            return
        stack = []
        walk: FrameType | None = frame
        while walk is not None:
            module = walk.f_globals.get("__name__", "")
            if module.startswith("server."):
                stack.append((module, walk.f_code.co_name))
            walk = walk.f_back
        stacks.append(stack[::-1])

    return stacks, profile


async def test_update_param_goes_down_the_layers_once(
    make_settings: Callable[..., Settings],
) -> None:
    # bucket_samples=1: the sample's bucket is written within the call, to the store.
    async with serve(make_settings(bucket_samples=1)) as base:
        async with httpx.AsyncClient(base_url=base, timeout=10) as api:
            vid, vh = await make_vehicle(api)
        async with await connect(base, "/ws/vehicle", vh["Authorization"][7:]) as car:
            iid = (await call(car, "start_instance", "s", vehicle_id=vid))["instance_id"]
            stacks, profile = recorder()
            sys.setprofile(profile)
            try:
                ack = await call(
                    car,
                    "update_param",
                    "u",
                    instance_id=iid,
                    samples=[
                        {"seq": 1, "ts": "2026-11-24T12:00:00.000Z", "lat": 43.9, "lon": 15.4}
                    ],
                )
            finally:
                sys.setprofile(None)
            assert ack["ok"] and ack["acked_through_seq"] == 1, ack
        async with httpx.AsyncClient(base_url=base, timeout=10) as api:
            page = (await api.get(f"/api/vehicles/{vid}/telemetry", headers=ADMIN)).json()
            assert [s["seq"] for s in page["samples"]] == [1]
    from_socket = [c for c in chains_of(stacks) if c and c[0] == "server.api"]
    assert from_socket, "the socket's handling was not seen"
    # The op reached the store, through the services, from the socket.
    assert ["server.api", "server.services", "server.storage"] in from_socket
    for chain in from_socket:
        ranks = [RANK.get(name, 5) for name in chain]
        assert ranks == sorted(ranks, reverse=True) and len(set(chain)) == len(chain), chain
