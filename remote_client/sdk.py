"""An async Python client for fleet-cloud's operator side, the one ``fleetctl`` runs on.

Each method is one call of the contract (``docs/api.md``) and
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

from collections.abc import AsyncGenerator, Iterable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime

from fleet_protocol.common import format_ts
from remote_client.names import AmbiguousName, UnknownVehicle, pick_named, pick_vehicle
from remote_client.sdk_admin import AdminCalls
from remote_client.sdk_control import ControlCalls
from remote_client.sdk_live import LiveCalls
from remote_client.sdk_session import Body, FleetApiError, OneOrMany, given, listed
from remote_client.times import when_text

__all__ = [
    "AmbiguousName",
    "Body",
    "FleetApiError",
    "FleetClient",
    "TrackPage",
    "UnknownVehicle",
    "pick_named",
    "pick_vehicle",
    "shown_status",
]

#: How long a stop waits for a vehicle out of reach: the longest a command may (1 h). A
#: stop that expired before the vehicle came back would never reach it.
STOP_TTL_S = 3600


def shown_status(command: Body) -> str:
    """A command's status as people read it: ``superseded`` for one a newer command took
    the place of (``cancelled`` with a detail ``superseded_by_stop`` or ``superseded_by
    <type> <id>``), else its status."""
    history = command.get("history") or []
    if (
        command.get("status") == "cancelled"
        and history
        and str(history[-1].get("detail") or "").startswith("superseded_by")
    ):
        return "superseded"
    return str(command.get("status"))


class FleetClient(ControlCalls, LiveCalls, AdminCalls):
    """One operator's (or field manager's) session with a fleet-cloud server."""

    # ---- the fleet -------------------------------------------------------------
    async def vehicles(self) -> Body:
        """``{"vehicles": [...]}``: the vehicles the caller may see."""
        body: Body = await self.call("GET", "/api/vehicles")
        return body

    async def instance_names(self) -> dict[str, str]:
        """Each current instance's vehicle name, for saying which boat a command went to."""
        fleet = (await self.vehicles())["vehicles"]
        return {
            v["instance_id"]: v.get("name") or v["vehicle_id"]
            for v in fleet
            if v.get("instance_id")
        }

    async def vehicle(self, vehicle_id: str) -> Body:
        """One vehicle's view (``GET /api/vehicles/{vehicle_id}``)."""
        body: Body = await self.call("GET", f"/api/vehicles/{vehicle_id}")
        return body

    async def connect(
        self, instance_id: str | None = None, *, vehicle_id: str | None = None
    ) -> Body:
        """``connect_instance``: ``{"instance": {...}}`` of an instance, or of a vehicle's
        current (or latest) one."""
        body = given(instance_id=instance_id, vehicle_id=vehicle_id)
        answer: Body = await self.call("POST", "/client/connect_instance", json=body)
        return answer

    async def params(self, instance_id: str, names: OneOrMany | None = None) -> Body:
        """``get_param``: ``{"params", "position", "updated_at"}`` (``names``: only those)."""
        query = {"instance_id": instance_id}
        if names:
            query["names"] = ",".join(listed(names))
        body: Body = await self.call("GET", "/client/get_param", params=query)
        return body

    # ---- names: a vehicle's display name works wherever its id does --------------
    async def resolve_vehicles(self, refs: OneOrMany) -> list[Body]:
        """The view of the vehicle each of ``refs`` names: its ``vehicle_id``, else its
        display name (exactly, then ignoring case). One ``GET /api/vehicles`` for all.
        Raises :class:`UnknownVehicle` or :class:`AmbiguousName`."""
        fleet = (await self.vehicles())["vehicles"]
        return [pick_vehicle(ref, fleet) for ref in listed(refs)]

    async def vehicle_id_of(self, ref: str) -> str:
        return str((await self.resolve_vehicles([ref]))[0]["vehicle_id"])

    async def instance_ids_of(self, refs: OneOrMany) -> list[str]:
        """The instance each of ``refs`` names: a vehicle (id or display name) stands for
        its current instance; an instance id is itself. Raises :class:`UnknownVehicle`
        (nothing by that name, or a vehicle that never started an instance) or
        :class:`AmbiguousName`."""
        fleet = (await self.vehicles())["vehicles"]
        current = {v["instance_id"] for v in fleet if v.get("instance_id")}
        out = []
        for ref in listed(refs):
            if ref in current and not any(v["vehicle_id"] == ref for v in fleet):
                out.append(ref)
                continue
            try:
                vehicle = pick_vehicle(ref, fleet)
            except UnknownVehicle:
                out.append(await self._older_instance(ref))
                continue
            if not vehicle.get("instance_id"):
                raise UnknownVehicle(
                    ref, f"vehicle {vehicle['vehicle_id']} has not started an instance yet"
                )
            out.append(vehicle["instance_id"])
        return out

    async def instance_id_of(self, ref: str) -> str:
        return (await self.instance_ids_of([ref]))[0]

    async def instance_of(self, ref: str) -> Body:
        """The instance ``ref`` names (as :meth:`instance_ids_of`) as ``connect`` shows it:
        its ``instance_id``, its vehicle's ``vehicle_id`` and ``name``, presence, control."""
        instance: Body = (await self.connect(await self.instance_id_of(ref)))["instance"]
        return instance

    async def instance_vehicles(self, instance_ids: Iterable[str]) -> dict[str, Body]:
        """Which vehicle each instance is: ``{instance_id: view}``, each view holding
        ``vehicle_id`` and ``name``; the current instances from one ``GET
        /api/vehicles``, any other as ``connect`` shows it."""
        wanted = set(instance_ids)
        if not wanted:
            return {}
        fleet = (await self.vehicles())["vehicles"]
        found = {v["instance_id"]: v for v in fleet if v.get("instance_id") in wanted}
        for instance_id in sorted(wanted - found.keys()):
            found[instance_id] = (await self.connect(instance_id))["instance"]
        return found

    async def _older_instance(self, ref: str) -> str:
        """``ref`` when the server knows it as an instance (one no longer current)."""
        try:
            await self.connect(ref)
        except FleetApiError as exc:
            if exc.status in (404, 422):
                raise UnknownVehicle(
                    ref, f"no vehicle id, vehicle name or instance id {ref!r} that you can see"
                ) from None
            raise
        return ref

    async def telemetry_pages(
        self,
        vehicle_id: str,
        *,
        since: When | None = None,
        until: When | None = None,
        page: int = 10_000,
        after: int = 0,
    ) -> AsyncGenerator[list[Body], None]:
        """Every stored sample of a vehicle in ``seq`` order (those after ``after``),
        ``page`` samples at a time; ``since``/``until`` as :data:`When`."""
        query: Body = {"limit": page, "after_seq": after, **_window(since, until)}
        while True:
            body = await self.call("GET", f"/api/vehicles/{vehicle_id}/telemetry", params=query)
            yield body["samples"]
            if body.get("next_after_seq") is None:
                return
            query["after_seq"] = body["next_after_seq"]

    async def track_pages(
        self,
        vehicle_id: str,
        *,
        since: When,
        until: When,
        fmt: str = "json",
        max_points: int | None = None,
    ) -> AsyncGenerator[TrackPage, None]:
        """The track from ``since`` (inclusive) to ``until`` (exclusive) in ``fmt``
        (``json``, ``geojson``, ``gpx``, ``csv``), one server page at a time: each page
        starts where the one before was cut (``next_from``). With ``max_points``, one
        page downsampled to that many points."""
        query: Body = {**_window(since, until), "format": fmt}
        if max_points is not None:
            query["max_points"] = max_points
        while True:
            response = await self._http.get(
                f"/api/vehicles/{vehicle_id}/track", params=query, headers=self._headers
            )
            if response.status_code >= 400:
                raise FleetApiError.of(response)
            if fmt == "json":
                content: Body | str = response.json()
                next_from = content.get("next_from") if isinstance(content, dict) else None
            else:
                content = response.text
                next_from = response.headers.get("X-Track-Next-From")
            yield TrackPage(content, next_from)
            if not next_from:
                return
            query["from"] = next_from

    async def event_log(
        self,
        *,
        vehicle_id: str | None = None,
        kind: str | None = None,
        since: When | None = None,
        until: When | None = None,
        limit: int = 1000,
        after: str | None = None,
    ) -> Body:
        """``GET /api/events``: ``{"events": [...], "next_after": cursor | None}``, oldest
        first; ``after``: the ``next_after`` of the page before; ``since``/``until`` as
        :data:`When` (``since="1h"``: the last hour)."""
        query = given(vehicle_id=vehicle_id, kind=kind, limit=limit, after=after)
        query.update(_window(since, until))
        body: Body = await self.call("GET", "/api/events", params=query)
        return body

    async def command(self, command_id: str) -> Body:
        """``GET /api/commands/{command_id}``: the command object."""
        body: Body = await self.call("GET", f"/api/commands/{command_id}")
        return body

    # ---- missions --------------------------------------------------------------
    async def submit(self, instance_ids: OneOrMany, command: Body, ttl_s: int = 30) -> Body:
        """``submit_control``: ``{"commands": [{instance_id, command_id, status}, ...]}``."""
        body = {"instance_ids": listed(instance_ids), "command": command, "ttl_s": ttl_s}
        answer: Body = await self.call("POST", "/client/submit_control", json=body)
        return answer

    async def stop(
        self, instance_ids: str | Sequence[str] | None = None, ttl_s: int = STOP_TTL_S
    ) -> Body:
        """Stop this instance or these, or, given None, every vehicle the caller can see (no
        lease needed). An empty list is a ``ValueError``: a filter that matched nothing
        never stops the whole fleet. The stop waits for a vehicle out of reach an hour (the
        longest a command may), not the contract's default 30 s."""
        if instance_ids is not None and not instance_ids:
            raise ValueError("stop: no instance given (None stops every vehicle you can see)")
        ids = ["*"] if instance_ids is None else _instances("stop", instance_ids)
        return await self.submit(ids, {"type": "stop", "args": {}}, ttl_s)

    async def go_to(
        self,
        instance_id: str | Sequence[str],
        lat: float,
        lon: float,
        *,
        speed_mps: float | None = None,
        ttl_s: int = 30,
    ) -> Body:
        """One instance, or several (each sent to the point: the answer's ``warnings``
        say they would meet there)."""
        args = given(lat=lat, lon=lon, speed_mps=speed_mps)
        ids = _instances("go_to", instance_id)
        return await self.submit(ids, {"type": "go_to", "args": args}, ttl_s)

    async def keep_station(
        self,
        instance_ids: str | Sequence[str],
        *,
        lat: float | None = None,
        lon: float | None = None,
        radius_m: float | None = None,
        ttl_s: int = 30,
    ) -> Body:
        """Hold ``lat, lon`` (both or neither: where each vehicle is) within ``radius_m``.
        One instance, or several."""
        args = given(lat=lat, lon=lon, radius_m=radius_m)
        ids = _instances("keep_station", instance_ids)
        return await self.submit(ids, {"type": "keep_station", "args": args}, ttl_s)

    async def follow_path(
        self,
        instance_id: str | Sequence[str],
        waypoints: Sequence[tuple[float, float]],
        *,
        speed_mps: float | None = None,
        plan: bool = False,
        ttl_s: int = 30,
    ) -> Body:
        """Waypoints as ``(lat, lon)``; ``plan``: the server routes around obstacles. One
        instance, or several (each given the path; planned, each its own route)."""
        points = [{"lat": lat, "lon": lon} for lat, lon in waypoints]
        args = given(waypoints=points, speed_mps=speed_mps, plan=plan or None)
        ids = _instances("follow_path", instance_id)
        return await self.submit(ids, {"type": "follow_path", "args": args}, ttl_s)

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

    async def audit(self, vehicle_id: str) -> list[Body]:
        """The vehicle's whole control log, oldest first (every page)."""
        entries: list[Body] = []
        after = 0
        while True:
            page: Body = await self.call(
                "GET", f"/api/vehicles/{vehicle_id}/audit", params={"after_seq": after}
            )
            entries += page["entries"]
            if page["next_after_seq"] is None:
                return entries
            after = page["next_after_seq"]

    # ---- live --------------------------------------------------------------------


@dataclass(frozen=True)
class TrackPage:
    """One page of a track: the JSON answer (``fmt`` json) or the text (the others), and
    where the next page starts (``None``: this was the last)."""

    content: Body | str
    next_from: str | None


def _instances(kind: str, given_ids: OneOrMany) -> list[str]:
    """A command's instances: one id, or several; none is a ``ValueError`` (not sent)."""
    ids = listed(given_ids)
    if not ids:
        raise ValueError(f"{kind}: no instance given")
    return ids


#: A point in time as the SDK takes it: an aware ``datetime`` (naive: UTC), ISO 8601
#: text, or a time as people type it, ``10m`` (ten minutes ago), ``2h``, ``now``
#: (``remote_client.times``; ``BadTime``, a ``ValueError``, for anything else).
When = datetime | str


def _window(since: When | None, until: When | None) -> Body:
    """The ``from`` and ``to`` query parameters of the times given, as the wire spells them."""
    out: Body = {}
    for key, when in (("from", since), ("to", until)):
        if isinstance(when, datetime):
            out[key] = format_ts(when if when.tzinfo else when.replace(tzinfo=UTC))
        elif when:
            out[key] = when_text(when)
    return out
