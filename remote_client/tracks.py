"""A track exported whole: the server's pages joined into one file of its format, and the
PNG plot (matplotlib, Agg backend). Pure but for writing the PNG."""

from __future__ import annotations

import io
import json
import math
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from fleet_protocol import track_coordinates, track_geometry

__all__ = ["FORMATS", "TrackJoiner", "plot_png"]

#: ``--format`` values, each also the file name ending that chooses it; the first on stdout.
FORMATS = ("json", "geojson", "gpx", "csv", "png")
GPX_NS = "http://www.topografix.com/GPX/1/1"


class TrackJoiner:
    """Pages of one format (as the server wrote them) joined into one document, as if the
    server had answered the whole window at once (``truncated: false``)."""

    def __init__(self, fmt: str) -> None:
        if fmt not in ("json", "geojson", "gpx", "csv"):
            raise ValueError(f"cannot join {fmt!r} pages")
        self.fmt = fmt
        self.points = 0
        self._json: dict[str, Any] | None = None
        self._csv: list[str] = []
        self._gpx: ET.Element | None = None

    def add(self, content: dict[str, Any] | str) -> int:
        """One page; how many points it held."""
        if self.fmt == "json":
            assert isinstance(content, dict)
            n = self._add_json(content)
        elif self.fmt == "geojson":
            n = self._add_geojson(json.loads(str(content)))
        elif self.fmt == "csv":
            n = self._add_csv(str(content))
        else:
            n = self._add_gpx(str(content))
        self.points += n
        return n

    def _add_json(self, page: dict[str, Any]) -> int:
        if self._json is None:
            self._json = {**page, "points": []}
        self._json["points"].extend(page["points"])
        return len(page["points"])

    def _add_geojson(self, page: dict[str, Any]) -> int:
        coords = track_coordinates(page["geometry"], len(page["properties"]["seqs"]))
        if self._json is None:
            self._json = page
        else:
            whole = self._json
            joined = track_coordinates(whole["geometry"], len(whole["properties"]["seqs"]))
            joined += coords
            self._json["geometry"] = track_geometry(joined)
            for key in ("times", "seqs"):
                self._json["properties"][key].extend(page["properties"][key])
        return len(coords)

    def _add_csv(self, text: str) -> int:
        lines = text.splitlines()
        if not self._csv:
            self._csv = lines[:1]
        self._csv.extend(lines[1:])
        return len(lines) - 1

    def _add_gpx(self, text: str) -> int:
        tree = ET.fromstring(text)
        points = tree.findall(f".//{{{GPX_NS}}}trkpt")
        if self._gpx is None:
            self._gpx = tree
        else:
            segment = self._gpx.find(f".//{{{GPX_NS}}}trkseg")
            assert segment is not None
            segment.extend(points)
        return len(points)

    def json_points(self) -> list[dict[str, Any]]:
        """The points of joined ``json`` pages."""
        assert self.fmt == "json"
        return list(self._json["points"]) if self._json is not None else []

    def text(self) -> str:
        """The joined document."""
        if self.fmt == "csv":
            return "\n".join(self._csv) + "\n" if self._csv else ""
        if self.fmt == "gpx":
            if self._gpx is None:
                return ""
            ET.register_namespace("", GPX_NS)
            body = ET.tostring(self._gpx, encoding="unicode")
            return f'<?xml version="1.0" encoding="UTF-8"?>\n{body}\n'
        if self._json is None:
            return ""
        if self.fmt == "json":
            self._json.update(truncated=False, next_from=None)
        else:
            self._json["properties"].update(truncated=False, next_from=None)
        return json.dumps(self._json, indent=1) + "\n"


def plot_png(points: Sequence[dict[str, Any]], title: str, out: str | Path | io.BytesIO) -> None:
    """The track on a plain lon/lat plot (metres kept square at its latitude), its start
    and end marked, written as a PNG. matplotlib's Agg backend: no display needed."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise RuntimeError(
            "PNG plots need matplotlib: pip install 'fleet-cloud[operator]'"
        ) from None
    figure = Figure(figsize=(8, 8), dpi=100)
    FigureCanvasAgg(figure)
    axes = figure.add_subplot()
    lons = [p["lon"] for p in points]
    lats = [p["lat"] for p in points]
    if points:
        axes.plot(lons, lats, color="#1f77b4", linewidth=1.5, label="track")
        axes.plot(lons[:1], lats[:1], "o", color="#2ca02c", markersize=8, label="start")
        axes.plot(lons[-1:], lats[-1:], "s", color="#d62728", markersize=8, label="end")
        mean_lat = sum(lats) / len(lats)
        axes.set_aspect(1 / max(math.cos(math.radians(mean_lat)), 0.01), adjustable="datalim")
        axes.legend(loc="best")
    else:
        axes.text(0.5, 0.5, "no points in this window", ha="center", transform=axes.transAxes)
    axes.set_xlabel("longitude (°)")
    axes.set_ylabel("latitude (°)")
    axes.ticklabel_format(useOffset=False)
    axes.grid(True, alpha=0.3)
    axes.set_title(title)
    figure.tight_layout()
    figure.savefig(out, format="png")
