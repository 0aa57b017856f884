// The map's offline base: a metric grid drawn for the view (no tiles, no network), a note
// in a corner saying its step, Leaflet's metric scale bar, and a tile layer under the grid
// only when the server names one (FLEET_MAP_TILE_URL).

import * as L from "/vendor/leaflet/leaflet-src.esm.js";

const M_PER_DEG = 111320;

/** 1, 2 or 5 times a power of ten: the grid step nearest ``metres`` (by ratio). */
export function niceStep(metres) {
  const p = 10 ** Math.floor(Math.log10(metres));
  let best = p;
  for (const m of [1, 2, 5, 10]) {
    if (Math.abs(Math.log(m * p / metres)) < Math.abs(Math.log(best / metres))) best = m * p;
  }
  return best;
}

/** A metric grid drawn for the view: lines every 1, 2 or 5 x 10^n metres, about 90 px
 * apart, every fifth one stronger. Needs no tiles and no network. */
const MetricGrid = L.Layer.extend({
  onAdd(map) {
    this._group = L.layerGroup().addTo(map);
    this._renderer = L.svg({ pane: "grid", padding: 0.2 });
    map.on("moveend zoomend resize", this._draw, this);
    this._draw();
  },
  onRemove(map) {
    map.off("moveend zoomend resize", this._draw, this);
    map.removeLayer(this._group);
    if (this.onStep) this.onStep(null);
  },
  _draw() {
    const map = this._map;
    const size = map.getSize();
    if (!size.x || !size.y) return;
    const centre = map.getCenter();
    const a = map.containerPointToLatLng([0, size.y / 2]);
    const b = map.containerPointToLatLng([size.x, size.y / 2]);
    const mPerPx = map.distance(a, b) / size.x;
    const step = niceStep(mPerPx * 90);
    const latStep = step / M_PER_DEG;
    const cos = Math.cos((Math.round(centre.lat * 10) / 10) * (Math.PI / 180));
    const lonStep = step / (M_PER_DEG * Math.max(cos, 0.01));
    const bounds = map.getBounds().pad(0.2);
    this._group.clearLayers();
    const lines = [];
    const south = bounds.getSouth();
    const north = bounds.getNorth();
    const west = bounds.getWest();
    const east = bounds.getEast();
    for (let i = Math.ceil(west / lonStep); i * lonStep <= east && lines.length < 400; i += 1) {
      lines.push([[[south, i * lonStep], [north, i * lonStep]], i % 5 === 0]);
    }
    for (let j = Math.ceil(south / latStep); j * latStep <= north && lines.length < 800; j += 1) {
      lines.push([[[j * latStep, west], [j * latStep, east]], j % 5 === 0]);
    }
    for (const [points, major] of lines) {
      L.polyline(points, {
        renderer: this._renderer,
        interactive: false,
        className: major ? "grid-line major" : "grid-line",
      }).addTo(this._group);
    }
    if (this.onStep) this.onStep(step);
  },
});

/** A corner note saying how far apart the grid's lines are. */
const GridNote = L.Control.extend({
  options: { position: "topleft" },
  onAdd() {
    this._el = L.DomUtil.create("div", "grid-note");
    return this._el;
  },
  show(step) {
    if (!this._el) return;
    if (step == null) this._el.textContent = "";
    else this._el.textContent = `grid ${step >= 1000 ? `${step / 1000} km` : `${step} m`}`;
  },
});

/** The base of ``map``: the scale bar, the grid and its note, and the server's tiles when
 * it names some (``config.tile_url``). Returns the base's entries of the layers control. */
export function addBase(map, config) {
  map.createPane("grid").style.zIndex = 250; // over the tiles (200), under the shapes (400)
  L.control.scale({ imperial: false, maxWidth: 160, position: "topleft" }).addTo(map);

  const grid = new MetricGrid();
  const note = new GridNote().addTo(map);
  grid.onStep = (step) => note.show(step);
  grid.addTo(map);
  const bases = { Grid: grid };
  if (config.tile_url) {
    const tiles = L.tileLayer(config.tile_url, {
      attribution: config.tile_attribution || "",
      maxZoom: 22,
      maxNativeZoom: 19,
    });
    tiles.addTo(map);
    bases.Tiles = tiles;
  }
  return bases;
}
