// The map's tooltips (a zone's or an obstacle's name, a planned path's vehicle): beside the
// pointer and whole on the map. Leaflet put a shape's tooltip at the shape's centre, left
// it there while the pointer stayed on the shape, and let it run past the map's edge (on
// a phone an operating area's name was cut off at the left and covered a boat).
//
// A zone answers the pointer only on or near its outline (a band EDGE_PX wide along it):
// its fill is not interactive, so that the pointer or a tap anywhere inside an operating
// area round the working water (almost everywhere) opens nothing over the boats.

import * as L from "/vendor/leaflet/leaflet-src.esm.js";

export const EDGE_PX = 16; // how wide the band along a zone's outline that shows its name is
const MARGIN_PX = 4; // between a tooltip and the map's edge

/** A tooltip that follows the pointer and is kept inside the map (wrapped when it is wider
 * than the map). */
const KeptTooltip = L.Tooltip.extend({
  _setPosition(pos) {
    const map = this._map;
    const el = this._container;
    const size = map.getSize();
    // no wider than the map, with room for the arrow's margin (.leaflet-tooltip-left/right)
    el.style.maxWidth = `${Math.max(0, size.x - 2 * MARGIN_PX - 12)}px`;
    L.Tooltip.prototype._setPosition.call(this, pos);
    const box = el.getBoundingClientRect();
    const view = map.getContainer().getBoundingClientRect();
    const left = box.left - view.left;
    const top = box.top - view.top;
    const x = Math.max(MARGIN_PX, Math.min(left, size.x - box.width - MARGIN_PX));
    const y = Math.max(MARGIN_PX, Math.min(top, size.y - box.height - MARGIN_PX));
    if (x !== left || y !== top) {
      L.DomUtil.setPosition(el, L.DomUtil.getPosition(el).add([x - left, y - top]));
    }
  },
});

// A finger has no hover: a tap opens a tooltip, which stays until the next tap on the map
// (Leaflet closes it then). The mouse events a browser makes up after a tap (a "mouseout"
// as the tap ends) do not close it.
let touch = false;
document.addEventListener("pointerdown", (e) => { touch = e.pointerType === "touch"; }, true);
document.addEventListener("pointermove", (e) => { if (e.pointerType === "mouse") touch = false; }, true);

/** ``text`` (HTML, already escaped) as a tooltip for ``layer``: beside the pointer, on the
 * map. */
export function bindKeptTooltip(layer, text) {
  const tip = new KeptTooltip({ sticky: true, className: "kept" }, layer);
  layer.bindTooltip(tip.setContent(text));
  layer.off("mouseout", layer.closeTooltip);
  layer.on("mouseout", () => { if (!touch) layer.closeTooltip(); });
  return layer;
}

/** A zone's outline as the only part of it that answers the pointer: a band ``EDGE_PX``
 * wide along it, drawn but not seen, carrying the zone's name. */
export function outlineBand(polygon, className, text) {
  const band = L.geoJSON(polygon, {
    style: { className, weight: EDGE_PX, opacity: 0, fill: false },
    interactive: true,
  });
  return bindKeptTooltip(band, text);
}
