// Longitudes across 180°. Leaflet draws 179.9° E and 179.9° W a world apart: a fleet at
// work across the antimeridian (Fiji, the Aleutians) fell in two, a zone split at 180
// (as GeoJSON asks) in two halves at the map's two ends, and a click east of 180 gave a
// longitude the server refuses. Every longitude is drawn within 180° of one meridian, the
// fleet's (its first position seen), and what the map gives back is sent within ±180.

let home = null; // the meridian drawn longitudes stay within 180° of

/** The meridian to draw near, from the first position seen (set once): true when it was
 * set now (what was drawn before is drawn again). */
export function setHome(lon) {
  if (home !== null || !Number.isFinite(lon)) return false;
  home = lon;
  return true;
}

/** ``lon`` as drawn: the same meridian, within 180° of home. */
export function drawn(lon) {
  return home === null ? lon : lon + 360 * Math.round((home - lon) / 360);
}

/** A point ({lat, lon}) as Leaflet takes it, drawn near home. */
export function at(p) {
  return [p.lat, drawn(p.lon)];
}

/** The step from longitude ``from`` to ``to`` the short way round, in degrees (±180). */
export function lonStep(from, to) {
  const d = (((to - from) % 360) + 540) % 360 - 180;
  return d === -180 && to > from ? 180 : d;
}

/** A longitude of the map (east of 180 once the map was panned across) as the wire
 * takes it: from -180 to 180. */
export function wireLon(lng) {
  if (lng >= -180 && lng <= 180) return lng;
  return lonStep(0, lng);
}
