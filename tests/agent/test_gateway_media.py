"""A gateway's local units and media frames, against a real server in this process.

A real uvicorn (``tests.live.serve``), the gateway's ``WsLink`` and
``UnitServer`` as ``fleet-agent gateway`` builds them, and real websockets
clients for the units and an operator. What went up is read off the
gateway's forwarding counters (``UnitServer.describe`` logs them). Every
wait has a deadline; where a route may still be settling, the sender sends
again until the receiver has a frame (``send_until_received``).
"""

from __future__ import annotations

import asyncio
import itertools
import json
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import httpx
import websockets

from fleet_protocol.media import MediaHeader, decode_media_frame, encode_media_frame
from server.settings import Settings
from tests.factories import ADMIN, make_user, make_vehicle, unique
from tests.live import connect, serve
from vehicle_client.gateway.units import UnitServer
from vehicle_client.transport.ws import WsLink

Frame = dict[str, Any]


@dataclass
class World:
    base: str
    units: UnitServer
    a: str  # two vehicles behind the gateway, each a local unit
    b: str
    operator: str  # a username on the server with read access to both
    operator_token: str

    def unit(self, vehicle_id: str, name: str | None = None) -> Any:
        """A local unit's connection to the gateway (``async with``), named or not."""
        url = f"ws://127.0.0.1:{self.units.port}/?vehicle_id={vehicle_id}"
        url += f"&unit={name}" if name is not None else ""
        return websockets.connect(url, compression=None)

    async def operator_ws(self) -> Any:
        return await connect(self.base, "/ws/client", self.operator_token)


@asynccontextmanager
async def gateway(
    make_settings: Callable[..., Settings], **unit_options: Any
) -> AsyncIterator[World]:
    async with serve(make_settings()) as base, httpx.AsyncClient(base_url=base, timeout=10) as api:
        a, _ = await make_vehicle(api)
        b, _ = await make_vehicle(api)
        body = {"gateway_id": unique("gw"), "vehicles": [a, b]}
        r = await api.post("/api/gateways", headers=ADMIN, json=body)
        assert r.status_code == 201, r.text
        operator, headers = await make_user(api, "operator", [a, b])
        link = WsLink(base, r.json()["token"])
        units = UnitServer(link, "127.0.0.1:0", **unit_options)
        await units.start()
        try:
            token = headers["Authorization"].removeprefix("Bearer ")
            yield World(base, units, a, b, operator, token)
        finally:
            await units.stop()
            await link.aclose()


def media(topic: str, payload: bytes) -> bytes:
    header = MediaHeader(topic=topic, ts=datetime.now(UTC), content_type="image/jpeg")
    return encode_media_frame(header, payload)


async def next_json(ws: Any, want: Callable[[Frame], bool], within_s: float = 10) -> Frame:
    """The first JSON frame ``want`` accepts (media frames skipped), by a deadline."""
    async with asyncio.timeout(within_s):
        while True:
            frame = await ws.recv()
            if isinstance(frame, str) and want(parsed := json.loads(frame)):
                return parsed


async def ack(ws: Any, op: str, op_id: str, **fields: Any) -> Frame:
    await ws.send(json.dumps({"op": op, "id": op_id, **fields}))
    return await next_json(ws, lambda f: f["op"] == "ack" and f["id"] == op_id)


async def next_media(ws: Any, topic: str, within_s: float = 10) -> bytes:
    """The payload of the first media frame on ``topic`` (JSON frames skipped)."""
    async with asyncio.timeout(within_s):
        while True:
            frame = await ws.recv()
            if isinstance(frame, bytes):
                header, payload = decode_media_frame(frame)
                if header.topic == topic:
                    return payload


async def send_until_received(sender: Any, topic: str, receiver: Any, tag: str) -> bytes:
    """Send ``tag-0``, ``tag-1``... on ``topic`` until ``receiver`` has one; that payload."""
    async with asyncio.timeout(15):
        for n in itertools.count():
            await sender.send(media(topic, f"{tag}-{n}".encode()))
            try:
                return await next_media(receiver, topic, within_s=0.5)
            except TimeoutError:
                continue
    raise AssertionError("unreachable")


def event_on(topic: str) -> Callable[[Frame], bool]:
    return lambda f: f["op"] == "event" and f["topic"] == topic


async def test_a_camera_frame_goes_up_only_once_asked_above_and_consumed_by_no_unit_below(
    make_settings: Callable[..., Settings],
) -> None:
    """API.md: a gateway forwards up what its own units do not consume and that someone
    upstream subscribed to."""
    async with gateway(make_settings) as w:
        cam = f"vehicle/{w.a}/camera/front"
        async with w.unit(w.a) as ua, w.unit(w.b) as ub:
            assert (await ack(ua, "register", "r", topics=[cam]))["ok"] is True
            assert (await ack(ub, "subscribe", "s", topics=[cam]))["ok"] is True
            # Only a unit beside it consumes the topic: delivered here, never sent up.
            await ua.send(media(cam, b"local-only"))
            assert await next_media(ub, cam) == b"local-only"
            assert (w.units.router.media_kept, w.units.router.media_up) == (1, 0)
            assert w.units.uplink.sent == 0

            async with await w.operator_ws() as op:
                assert (await ack(op, "subscribe", "o", topics=[cam]))["ok"] is True
                consumer = f"user:{w.operator}"
                await next_json(
                    ua, lambda f: f["op"] == "routes" and consumer in f["produces"].get(cam, [])
                )
                # Asked above as well, but a unit beside it consumes it: still kept below.
                await ua.send(media(cam, b"still-local"))
                assert await next_media(ub, cam) == b"still-local"
                assert (w.units.router.media_kept, w.units.router.media_up) == (2, 0)
                assert w.units.uplink.sent == 0
                # No unit below consumes it any more: up it goes. The operator's first
                # frame is one sent after that ("still-local" never went up).
                assert (await ack(ub, "unsubscribe", "u", topics=[cam]))["ok"] is True
                got = await send_until_received(ua, cam, op, "up")
                assert got.startswith(b"up-")
                assert w.units.router.media_up >= 1 and w.units.uplink.sent >= 1


async def test_a_frame_from_above_reaches_the_unit_subscribed_to_it(
    make_settings: Callable[..., Settings],
) -> None:
    async with gateway(make_settings) as w:
        mask = f"user/{w.operator}/image/{w.b}"  # an image for unit b (its to read)
        async with w.unit(w.b) as ub, await w.operator_ws() as op:
            assert (await ack(ub, "subscribe", "s", topics=[mask]))["ok"] is True
            got = await send_until_received(op, mask, ub, "mask")
            assert got.startswith(b"mask-")


async def test_a_unit_publishes_media_only_in_its_own_namespace(
    make_settings: Callable[..., Settings],
) -> None:
    async with gateway(make_settings) as w:
        async with w.unit(w.a) as ua:
            await ua.send(media(f"vehicle/{w.b}/camera", b"not mine"))
            refused = await next_json(ua, lambda f: f["op"] == "error")
            assert refused["error"]["code"] == "forbidden"
            assert f"vehicle/{w.a}/" in refused["error"]["message"]
            assert [d["field"] for d in refused["error"]["details"]] == ["topic"]
            await ua.send(media(f"vehicle/{w.a}/notes", b"not media"))
            invalid = await next_json(ua, lambda f: f["op"] == "error")
            assert invalid["error"]["code"] == "invalid"
            assert "not a media topic" in invalid["error"]["message"]
            assert [d["field"] for d in invalid["error"]["details"]] == ["topic"]
            assert (w.units.router.media_up, w.units.router.media_kept) == (0, 0)


async def test_an_oversize_frame_is_refused_and_the_unit_stays_connected(
    make_settings: Callable[..., Settings],
) -> None:
    limit = 64 * 1024
    async with gateway(make_settings, max_media_bytes=limit) as w:
        cam = f"vehicle/{w.a}/sonar"
        async with w.unit(w.a) as ua, w.unit(w.b) as ub:
            assert (await ack(ub, "subscribe", "s", topics=[cam]))["ok"] is True
            big = media(cam, b"x" * limit)
            await ua.send(big)
            refused = await next_json(ua, lambda f: f["op"] == "error")
            assert refused["error"]["code"] == "too_large"
            assert f"at most {limit} bytes" in refused["error"]["message"]
            assert str(len(big)) in refused["error"]["message"]
            # The same socket still works, and the big frame went nowhere.
            await ua.send(media(cam, b"small"))
            assert await next_media(ub, cam) == b"small"


async def test_a_media_flood_keeps_the_latest_and_leaves_room_for_json(
    make_settings: Callable[..., Settings],
) -> None:
    async with gateway(make_settings, media_up_per_s=20) as w:
        cam, status = f"vehicle/{w.a}/video", f"vehicle/{w.b}/status"
        async with w.unit(w.a) as ua, w.unit(w.b) as ub, await w.operator_ws() as op:
            assert (await ack(ua, "register", "r", topics=[cam]))["ok"] is True
            assert (await ack(ub, "register", "r", topics=[status]))["ok"] is True
            assert (await ack(op, "subscribe", "o", topics=[cam, status]))["ok"] is True
            await send_until_received(ua, cam, op, "warm")
            # 200 frames at once, against 20 a second up: 10 s of video if queued.
            for n in range(200):
                await ua.send(media(cam, b"%03d" % n + b"v" * 8192))
            # Meanwhile a unit's op is acked by the server and its publish arrives.
            async with asyncio.timeout(3):
                assert (await ack(ub, "subscribe", "s", topics=[f"vehicle/{w.b}/x"]))["ok"]
                await ub.send(json.dumps({"op": "publish", "topic": status, "data": {"ok": 1}}))
                assert (await next_json(op, event_on(status)))["data"] == {"ok": 1}
            # The newest frame is never replaced: it gets there.
            async with asyncio.timeout(10):
                while not (await next_media(op, cam)).startswith(b"199"):
                    pass
            up = w.units.uplink
            assert up.replaced > 0
            assert w.units.router.media_up == up.sent + up.replaced + up.dropped + up.waiting
