// Where each vehicle's label goes so that no label covers another label, a marker or a
// small thing drawn on the map (a station's circle), nor runs off the map: for each marker
// (top to bottom), the first of a list of places around it that is free; if none is, the
// one that covers least. Pure: rectangles in, offsets out.

const GAP = 5;

function candidates(r, w, h) {
  const out = [
    [r + GAP, -h / 2], // right
    [-(r + GAP) - w, -h / 2], // left
    [-w / 2, -(r + GAP) - h], // above
    [-w / 2, r + GAP], // below
    [r, -r - h], // above right
    [r, r], // below right
    [-r - w, -r - h], // above left
    [-r - w, r], // below left
  ];
  for (let k = 1; k <= 4; k += 1) {
    // further out, in steps of one label's height
    const step = k * (h + 2);
    out.push([r + GAP, -h / 2 - step], [r + GAP, -h / 2 + step]);
    out.push([-(r + GAP) - w, -h / 2 - step], [-(r + GAP) - w, -h / 2 + step]);
  }
  return out;
}

function overlap(a, b) {
  const x = Math.min(a.x + a.w, b.x + b.w) - Math.max(a.x, b.x);
  const y = Math.min(a.y + a.h, b.y + b.h) - Math.max(a.y, b.y);
  return x > 0 && y > 0 ? x * y : 0;
}

/** How much of ``box`` lies outside the view (0 when there is no view). */
function outside(box, view) {
  if (!view) return 0;
  const inside = overlap(box, { x: 0, y: 0, w: view.w, h: view.h });
  return box.w * box.h - inside;
}

/**
 * anchors: [{id, x, y, w, h}] (the marker's centre on screen, its label's size);
 * r: a marker's radius in pixels; view: {w, h}, the map's size (a label cut by its
 * edge costs as much as one covered); clear: [{x, y, w, h}], other boxes no label should
 * cover. Returns a Map id -> {dx, dy}, the label's top-left corner relative to its
 * marker's centre.
 */
export function placeLabels(anchors, r = 12, view = null, clear = []) {
  const taken = anchors.map((a) => ({ x: a.x - r, y: a.y - r, w: 2 * r, h: 2 * r }));
  taken.push(...clear);
  const placed = new Map();
  const order = [...anchors].sort((a, b) => a.y - b.y || a.x - b.x || (a.id < b.id ? -1 : 1));
  for (const a of order) {
    let best = null;
    for (const [dx, dy] of candidates(r, a.w, a.h)) {
      const box = { x: a.x + dx, y: a.y + dy, w: a.w, h: a.h };
      const cost = taken.reduce((sum, t) => sum + overlap(box, t), outside(box, view));
      if (!best || cost < best.cost) best = { dx, dy, box, cost };
      if (cost === 0) break;
    }
    placed.set(a.id, { dx: best.dx, dy: best.dy });
    taken.push(best.box);
  }
  return placed;
}
