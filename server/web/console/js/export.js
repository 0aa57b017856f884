// The replay's window exported: the server's track of each chosen vehicle in the format
// asked for (GPX: one ``trk`` each; GeoJSON: one Feature each), joined in one file. The
// server names each track by its vehicle ("H2OmniX Alpha (demo-usv-1)"); the file is
// named by the vehicles too ("fleet-replay-H2OmniX-Alpha_H2OmniX-Bravo-2026-11-25T004351Z
// .gpx"), not by their ids alone, and its name is safe on any file system.

import { h, toast } from "./ui.js";

const NAMED = 3; // vehicles named in a file's name at most, then "and-N-more"
const TYPES = { geojson: "application/geo+json", gpx: "application/gpx+xml" };

/** Text as a part of a file's name: letters and digits (of any script) kept, every other
 * run of characters (spaces, dots, / \ : * ? " < > |) one "-", none at either end, 40
 * characters at most; "" when nothing is left. */
export function fileSafe(text) {
  return String(text || "").normalize("NFC").replace(/[^\p{L}\p{N}]+/gu, "-").slice(0, 40)
    .replace(/^-+|-+$/g, "");
}

/** Each vehicle as a file's name says it: its name, and its id after it when another
 * vehicle the console knows has the same name (letter case aside: a file system may not
 * tell them apart), or the id alone for a vehicle with no name. */
export function fileLabels(ids, fleet) {
  const named = new Map(); // a name as a file says it -> how many vehicles have it
  for (const v of fleet.vehicles.values()) {
    const name = fileSafe(v.view.name).toLowerCase();
    named.set(name, (named.get(name) || 0) + 1);
  }
  return ids.map((id) => {
    const v = fleet.vehicles.get(id);
    const name = fileSafe(v && v.view.name);
    if (!name) return fileSafe(id);
    return named.get(name.toLowerCase()) === 1 ? name : `${name}-${fileSafe(id)}`;
  });
}

/** The file's name: the vehicles, then the window's start in UTC (said by its "Z"). */
export function fileName(ids, fleet, start, format) {
  const labels = fileLabels(ids, fleet);
  const shown = labels.slice(0, NAMED);
  if (labels.length > NAMED) shown.push(`and-${labels.length - NAMED}-more`);
  const stamp = `${new Date(start).toISOString().slice(0, 19).replace(/:/g, "")}Z`; // 2026-11-25T004351Z
  return `fleet-replay-${shown.join("_")}-${stamp}.${format}`;
}

/** The window from ``start`` to ``end`` (ms) of the vehicles ``ids``, downloaded as one
 * file in ``format`` ("gpx" or "geojson"). */
export async function exportWindow(ctx, ids, start, end, format) {
  const from = new Date(start).toISOString();
  const to = new Date(end).toISOString();
  try {
    const texts = await Promise.all(ids.map((id) => ctx.api.request(
      "GET", `/api/vehicles/${encodeURIComponent(id)}/track`,
      { query: { from, to, format }, raw: true },
    )));
    const body = format === "geojson"
      ? JSON.stringify({
        type: "FeatureCollection", features: texts.map((t) => JSON.parse(t)), properties: { from, to },
      }, null, 1)
      : mergeGpx(texts);
    const a = h("a", {
      href: URL.createObjectURL(new Blob([body], { type: TYPES[format] })),
      download: fileName(ids, ctx.fleet, start, format),
    });
    document.body.append(a);
    a.click();
    a.remove();
  } catch (e) {
    toast(`export: ${e.message}`, "error");
  }
}

/** One GPX document with every vehicle's track (the server gives one per vehicle). */
function mergeGpx(texts) {
  const parser = new DOMParser();
  const docs = texts.map((t) => parser.parseFromString(t, "application/xml"));
  const [first, ...rest] = docs;
  const root = first.documentElement;
  for (const doc of rest) {
    for (const trk of doc.getElementsByTagName("trk")) root.append(first.importNode(trk, true));
  }
  return new XMLSerializer().serializeToString(first);
}
