"""Telemetry views: ``/api/vehicles/{vehicle_id}/track`` and ``.../telemetry``.

Track: ``from`` inclusive, ``to`` exclusive (defaults: ``to`` = now, ``from`` =
``to`` - 24 h). Without ``max_points`` at most 10,000 points
(:data:`~server.domain.track.TRACK_PAGE_CAP`), then ``truncated: true`` and
``next_from`` (the ``from`` of the next page). With ``max_points`` (2-10,000)
the window is downsampled keeping its shape. ``format``: ``json`` (default),
``geojson``, ``gpx``, ``csv``; the last three also say ``X-Track-Truncated``
and ``X-Track-Next-From`` in headers.
"""

from __future__ import annotations

from datetime import timedelta
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, Path, Query
from fastapi.responses import Response

from fleet_protocol import TelemetryPage, TimeBound, Track, format_ts
from server.api import track_formats
from server.api.deps import ServicesDep, Viewer
from server.api.responses import SafeJSONResponse
from server.domain.track import TRACK_PAGE_CAP
from server.domain.windows import ordered, window

router = APIRouter(tags=["telemetry"])

MAX_PAGE = 10_000
DEFAULT_WINDOW = timedelta(hours=24)


async def _visible_record(
    vehicle_id: Annotated[str, Path(min_length=1, max_length=64)],
    user: Viewer,
    s: ServicesDep,
) -> dict[str, Any]:
    # 404: unknown, or not for this caller
    return await s.views.visible_vehicle(user, vehicle_id)


async def _visible_vehicle(vehicle: Annotated[dict[str, Any], Depends(_visible_record)]) -> str:
    return str(vehicle["vehicle_id"])


VisibleRecord = Annotated[dict[str, Any], Depends(_visible_record)]
VisibleVehicle = Annotated[str, Depends(_visible_vehicle)]
From = Annotated[TimeBound | None, Query(alias="from")]
To = Annotated[TimeBound | None, Query(alias="to")]


@router.get("/api/vehicles/{vehicle_id}/track", response_model=Track)
async def track(
    vehicle: VisibleRecord,
    s: ServicesDep,
    start: From = None,
    end: To = None,
    max_points: Annotated[int | None, Query(ge=2, le=TRACK_PAGE_CAP)] = None,
    fmt: Annotated[Literal["json", "geojson", "gpx", "csv"], Query(alias="format")] = "json",
) -> Response:
    vehicle_id = str(vehicle["vehicle_id"])
    start, end = window(start, end, s.clock(), DEFAULT_WINDOW)
    result = await s.telemetry.track(vehicle_id, start, end, max_points)
    headers = track_formats.paging_headers(result)
    media = track_formats.MEDIA_TYPES.get(fmt)
    name = track_formats.track_name(vehicle_id, await s.views.shown_name(vehicle))
    if fmt == "geojson":
        feature = track_formats.geojson(result, name)
        return SafeJSONResponse(feature, media_type=media, headers=headers)
    if fmt == "gpx":
        gap = s.settings.offline_after_s  # a gap longer: out of contact, a segment ends
        return Response(track_formats.gpx(result, name, gap), media_type=media, headers=headers)
    if fmt == "csv":
        return Response(track_formats.csv_text(result), media_type=media, headers=headers)
    body = Track.model_construct(  # from the store: checked when it came in
        vehicle_id=vehicle_id,
        points=track_formats.json_points(result),
        truncated=result.truncated,
        next_from=result.next_from,
    )
    return SafeJSONResponse(body.model_dump(mode="json"))


@router.get("/api/vehicles/{vehicle_id}/telemetry")
async def telemetry(
    vehicle_id: VisibleVehicle,
    s: ServicesDep,
    start: From = None,
    end: To = None,
    after_seq: Annotated[int, Query(ge=-1, le=2**62)] = -1,
    limit: Annotated[int, Query(ge=1, le=MAX_PAGE)] = 1000,
) -> TelemetryPage:
    ordered(start, end)
    samples, next_after = await s.telemetry.page(
        vehicle_id, after_seq=after_seq, start=start, end=end, limit=limit
    )
    return TelemetryPage(
        samples=[{**d, "ts": format_ts(d["ts"])} for d in samples], next_after_seq=next_after
    )
