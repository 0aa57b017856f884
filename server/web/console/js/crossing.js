// Whether a straight way runs into a shape on the map: a known fixed obstacle (a pier, a
// moored barge) or a no-go zone. A go_to, a station away from the boat or a path not
// planned go straight: the console asks before one that runs into an obstacle (the server
// queues it as asked, with a note after), and says when a zone drawn later is across a
// mission under way. Pure: points in, a shape out.

import { lonStep } from "./wrap.js";

const M_PER_DEG = 111320;

/** ``p`` in metres east and north of ``ref`` (flat: fine over a few km). */
function local(ref, p) {
  return [lonStep(ref.lon, p.lon) * M_PER_DEG * Math.cos((ref.lat * Math.PI) / 180),
    (p.lat - ref.lat) * M_PER_DEG];
}

function side(a, b, c) {
  return Math.sign((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]));
}

function onSegment(a, b, c) { // c on ab, known to be on its line
  return Math.min(a[0], b[0]) <= c[0] && c[0] <= Math.max(a[0], b[0])
    && Math.min(a[1], b[1]) <= c[1] && c[1] <= Math.max(a[1], b[1]);
}

function segmentsMeet(a, b, c, d) {
  const [s1, s2, s3, s4] = [side(a, b, c), side(a, b, d), side(c, d, a), side(c, d, b)];
  if (s1 !== s2 && s3 !== s4) return true;
  return (s1 === 0 && onSegment(a, b, c)) || (s2 === 0 && onSegment(a, b, d))
    || (s3 === 0 && onSegment(c, d, a)) || (s4 === 0 && onSegment(c, d, b));
}

function inRing(p, ring) {
  let inside = false;
  for (let i = 0, j = ring.length - 1; i < ring.length; j = i, i += 1) {
    const [xi, yi] = ring[i];
    const [xj, yj] = ring[j];
    if ((yi > p[1]) !== (yj > p[1]) && p[0] < ((xj - xi) * (p[1] - yi)) / (yj - yi) + xi) inside = !inside;
  }
  return inside;
}

/** Whether the straight leg from ``a`` to ``b`` ({lat, lon}) touches the polygon (GeoJSON
 * rings of [lon, lat]: the outline, then holes). */
function legMeets(a, b, rings) {
  const planar = rings.map((ring) => ring.map(([lon, lat]) => local(a, { lat, lon })));
  const [pa, pb] = [[0, 0], local(a, b)];
  for (const ring of planar) {
    for (let i = 1; i < ring.length; i += 1) if (segmentsMeet(pa, pb, ring[i - 1], ring[i])) return true;
  }
  const [outline, ...holes] = planar;
  const within = (p) => inRing(p, outline) && !holes.some((h) => inRing(p, h));
  return within(pa) || within(pb);
}

/** The first shape (an obstacle, a zone: ``{name, polygon}``) the straight way along
 * ``route`` ({lat, lon} points, from where the boat is) runs into, or null. */
export function shapeOnTheWay(route, shapes) {
  for (let i = 1; i < route.length; i += 1) {
    for (const o of shapes || []) {
      if (o.polygon && legMeets(route[i - 1], route[i], o.polygon.coordinates)) return o;
    }
  }
  return null;
}
