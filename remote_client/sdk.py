"""An async Python client for fleet-cloud's operator side, the one ``fleetctl`` runs on.

Each method is one call of the contract (``../shared/design/API.md``) and
returns its JSON answer as the contract spells it; a refusal raises
:class:`FleetApiError` with the error envelope's ``code``, ``message`` and
``details``. Network failures are httpx's (``httpx.HTTPError``) and, for
:meth:`FleetClient.events`, ``OSError`` / ``websockets.InvalidHandshake``.

    async with FleetClient("https://fleet.example.org", token) as fleet:
        for vehicle in (await fleet.vehicles())["vehicles"]:
            ...
        await fleet.go_to(instance_id, 43.94, 15.44, speed_mps=1.5)

Tests hand it an ``httpx.AsyncClient`` on the app itself (``client=``).
"""

from __future__ import annotations

import json
from collections.abc import AsyncGenerator, Sequence
from types import TracebackType
from typing import Any, Self

import httpx
import websockets

from fleet_protocol.links import CLOSE_FORBIDDEN, CLOSE_UNAUTHORIZED, websocket_url

Body = dict[str, Any]

#: WebSocket close codes that refuse the token or the socket, as HTTP statuses.
REFUSING_CLOSE_CODES = {CLOSE_UNAUTHORIZED: 401, CLOSE_FORBIDDEN: 403}
#: The HTTP status an error code has on the HTTP routes (a refused op is acked with the code).
STATUS_OF_CODE = {
    "unauthorized": 401, "forbidden": 403, "not_found": 404, "invalid": 422, "rate_limited": 429,
}  # fmt: skip


class FleetApiError(Exception):
    """The server refused a call: its HTTP status and the contract's error envelope."""

    def __init__(
        self, status: int, code: str, message: str, details: list[dict[str, Any]] | None = None
    ) -> None:
        super().__init__(f"{status} {code}: {message}")
        self.status = status
        self.code = code
        self.message = message
        self.details = details or []

    @classmethod
    def of(cls, response: httpx.Response) -> FleetApiError:
        try:
            error = response.json()["error"]
            return cls(response.status_code, error["code"], error["message"], error.get("details"))
        except (ValueError, KeyError, TypeError):
            return cls(response.status_code, "http_error", response.text[:500])


class FleetClient:
    """One operator's (or field manager's) session with a fleet-cloud server."""

    def __init__(
        self,
        server: str,
        token: str,
        *,
        client: httpx.AsyncClient | None = None,
        timeout_s: float = 30.0,
    ) -> None:
        self.server = server.rstrip("/")
        self._headers = {"Authorization": f"Bearer {token}"}
        self._own_client = client is None
        self._http = client or httpx.AsyncClient(base_url=self.server, timeout=timeout_s)

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        if self._own_client:
            await self._http.aclose()

    async def call(self, method: str, path: str, **kwargs: Any) -> Any:
        """Any route of the contract: its JSON answer, or :class:`FleetApiError`."""
        response = await self._http.request(method, path, headers=self._headers, **kwargs)
        if response.status_code >= 400:
            raise FleetApiError.of(response)
        return response.json()

    # ---- the fleet -------------------------------------------------------------
    async def vehicles(self) -> Body:
        """``{"vehicles": [...]}``: the vehicles the caller may see."""
        body: Body = await self.call("GET", "/api/vehicles")
        return body

    async def telemetry_pages(
        self,
        vehicle_id: str,
        *,
        since: str | None = None,
        until: str | None = None,
        page: int = 10_000,
    ) -> AsyncGenerator[list[Body], None]:
        """Every stored sample of a vehicle in ``seq`` order, ``page`` samples at a time."""
        query: Body = {"limit": page, "after_seq": 0}
        query.update({k: v for k, v in (("from", since), ("to", until)) if v})
        while True:
            body = await self.call("GET", f"/api/vehicles/{vehicle_id}/telemetry", params=query)
            yield body["samples"]
            if body.get("next_after_seq") is None:
                return
            query["after_seq"] = body["next_after_seq"]

    # ---- missions --------------------------------------------------------------
    async def submit(self, instance_ids: Sequence[str], command: Body, ttl_s: int = 30) -> Body:
        """``submit_control``: ``{"commands": [{instance_id, command_id, status}, ...]}``."""
        body = {"instance_ids": list(instance_ids), "command": command, "ttl_s": ttl_s}
        answer: Body = await self.call("POST", "/client/submit_control", json=body)
        return answer

    async def stop(self, instance_ids: Sequence[str] | None = None) -> Body:
        """Stop these instances, or every vehicle the caller can see (no lease needed)."""
        return await self.submit(instance_ids or ["*"], {"type": "stop", "args": {}})

    async def go_to(
        self,
        instance_id: str,
        lat: float,
        lon: float,
        *,
        speed_mps: float | None = None,
        ttl_s: int = 30,
    ) -> Body:
        args = _given(lat=lat, lon=lon, speed_mps=speed_mps)
        return await self.submit([instance_id], {"type": "go_to", "args": args}, ttl_s)

    async def keep_station(
        self,
        instance_ids: Sequence[str],
        *,
        lat: float | None = None,
        lon: float | None = None,
        radius_m: float | None = None,
        ttl_s: int = 30,
    ) -> Body:
        """Hold ``lat, lon`` (both or neither: where each vehicle is) within ``radius_m``."""
        args = _given(lat=lat, lon=lon, radius_m=radius_m)
        return await self.submit(instance_ids, {"type": "keep_station", "args": args}, ttl_s)

    async def follow_path(
        self,
        instance_id: str,
        waypoints: Sequence[tuple[float, float]],
        *,
        speed_mps: float | None = None,
        plan: bool = False,
        ttl_s: int = 30,
    ) -> Body:
        """Waypoints as ``(lat, lon)``; ``plan``: the server routes around obstacles."""
        points = [{"lat": lat, "lon": lon} for lat, lon in waypoints]
        args = _given(waypoints=points, speed_mps=speed_mps, plan=plan or None)
        return await self.submit([instance_id], {"type": "follow_path", "args": args}, ttl_s)

    async def commands(self, instance_id: str) -> Body:
        """``get_fbmessage``: ``{"control_mode", "commands": [command object, ...]}``."""
        params = {"instance_id": instance_id}
        body: Body = await self.call("GET", "/client/get_fbmessage", params=params)
        return body

    async def cancel(self, command_id: str) -> Body:
        body: Body = await self.call(
            "POST", "/client/cancel_command", json={"command_id": command_id}
        )
        return body

    # ---- control ---------------------------------------------------------------
    async def request_control(self, instance_id: str) -> Body:
        return await self._on_instance("request_control", instance_id)

    async def control_requests(self, instance_id: str | None = None) -> Body:
        """``{"requests": [...]}``: the pending ones the caller may answer."""
        params = {"instance_id": instance_id} if instance_id else {}
        body: Body = await self.call("GET", "/client/control_requests", params=params)
        return body

    async def grant_control(self, instance_id: str, user: str, duration_s: int = 3600) -> Body:
        """The lease ``{holder, granted_by, expires_at}`` (a field manager or an admin)."""
        body = {"instance_id": instance_id, "user": user, "duration_s": duration_s}
        answer: Body = await self.call("POST", "/client/grant_control", json=body)
        return answer

    async def revoke_control(self, instance_id: str) -> Body:
        return await self._on_instance("revoke_control", instance_id)

    async def release_control(self, instance_id: str) -> Body:
        return await self._on_instance("release_control", instance_id)

    async def _on_instance(self, route: str, instance_id: str) -> Body:
        body: Body = await self.call("POST", f"/client/{route}", json={"instance_id": instance_id})
        return body

    # ---- live --------------------------------------------------------------------
    async def events(
        self, topics: Sequence[str], *, throttle_ms: int = 0
    ) -> AsyncGenerator[Body, None]:
        """Subscribe on ``/ws/client`` and yield its ``event`` and ``lagging`` pushes (each
        topic's current state first, ``snapshot: true``) until the server closes.

        A refused token or subscription raises :class:`FleetApiError`; a lost link ends
        the iteration (``websockets.ConnectionClosed`` is not raised).
        """
        subscribe: Body = {"op": "subscribe", "id": "events", "topics": list(topics)}
        if throttle_ms:
            subscribe["throttle_ms"] = throttle_ms
        async with websockets.connect(
            websocket_url(self.server, "/ws/client"),
            additional_headers=self._headers,
            open_timeout=30,
        ) as ws:
            try:
                await ws.send(json.dumps(subscribe))
                async for frame in ws:
                    if not isinstance(frame, str):
                        continue  # media frames: not for this iterator
                    push = json.loads(frame)
                    if push.get("op") == "ack" and not push.get("ok"):
                        error = push.get("error") or {}
                        code = error.get("code", "refused")
                        status = STATUS_OF_CODE.get(code, 409)
                        message = error.get("message", "")
                        raise FleetApiError(status, code, message, error.get("details"))
                    if push.get("op") in ("event", "lagging"):
                        yield push
            except websockets.ConnectionClosed as exc:
                closing = REFUSING_CLOSE_CODES.get(exc.rcvd.code) if exc.rcvd else None
                if closing is not None and exc.rcvd is not None:
                    raise FleetApiError(closing, "refused", exc.rcvd.reason) from None


def _given(**fields: Any) -> Body:
    """The fields that are set (a command's optional ``args`` left out when ``None``)."""
    return {k: v for k, v in fields.items() if v is not None}
