// Replay: when each vehicle was out of contact. The server records a `presence` event when
// a vehicle goes offline (no contact for `offline_after_s`) and when it is heard again;
// from its last position heard until then the track is drawn dashed and grey, the marker
// waits greyed where it was last heard, the timeline has a grey band and the replay says
// "offline 10:02:11–10:05:40".

import { L } from "./map.js";
import { lastAtOrBefore } from "./replay.js";
import { clock, h } from "./ui.js";
import { at } from "./wrap.js";

/** The periods a vehicle was out of contact within [start, end], from its events and
 * its track (both sorted by ``t``): [{from, to, open}], ``open`` when it was still offline
 * at the window's end. The server records `presence: offline` only `offline_after_s`
 * after the last contact: the period begins at the last position heard before that
 * event (a vehicle in contact sends its positions), when it came after the vehicle was
 * last said online or started, else at the event. It ends at the next sign of contact
 * (any other presence, or its instance started, resumed or finished). */
export function offlinePeriods(events, points, start, end) {
  const out = [];
  let from = null;
  let online = -Infinity; // when the vehicle was last said to be in contact
  for (const e of events) {
    const d = e.data || {};
    const offline = e.kind === "presence" && d.presence === "offline";
    const contact = (e.kind === "presence" && d.presence !== "offline" && d.presence !== "stale")
      || e.kind === "instance";
    if (offline && from === null) {
      const heard = points[lastAtOrBefore(points, e.t)];
      from = heard && heard.t >= online ? heard.t : e.t;
    } else if (contact && from !== null) {
      out.push({ from, to: e.t, open: false });
      from = null;
    }
    if (contact) online = e.t;
  }
  if (from !== null && from < end) out.push({ from, to: end, open: true });
  return out.filter((p) => p.to > start);
}

/** The period ``t`` falls in, or null. */
export function periodAt(periods, t) {
  return periods.find((p) => p.from <= t && t <= p.to) || null;
}

/** "offline 10:02:11–10:05:40" (to the window's end: "offline since 10:02:11"). */
export function offlineText(p) {
  return p.open ? `offline since ${clock(p.from)}` : `offline ${clock(p.from)}–${clock(p.to)}`;
}

/** The track as runs of [lat, lon]: each {offline, pts}. A step between two samples is
 * offline when it spans part of an offline period (the samples on either side of the
 * gap are joined by a dashed line: nothing is known of the way between). */
export function trackRuns(points, periods) {
  const runs = [];
  for (let i = 1; i < points.length; i++) {
    const a = points[i - 1];
    const b = points[i];
    const offline = periods.some((p) => a.t < p.to && b.t > p.from);
    const last = runs[runs.length - 1];
    if (last && last.offline === offline) last.pts.push(at(b));
    else runs.push({ offline, pts: [at(a), at(b)] });
  }
  if (!runs.length && points.length) runs.push({ offline: false, pts: [at(points[0])] });
  return runs;
}

/** Draw a vehicle's track on ``layer``: in contact in its colour, offline dashed grey. */
export function drawTrack(layer, id, points, periods, colour) {
  for (const run of trackRuns(points, periods)) {
    L.polyline(run.pts, run.offline
      ? { color: "#78909c", weight: 3, opacity: 0.9, dashArray: "6 8", interactive: false,
        className: `replay-track replay-offline replay-offline-${id}` }
      : { color: colour, weight: 3, opacity: 0.55, interactive: false, className: "replay-track" })
      .addTo(layer);
  }
}

/** The offline periods as grey bands on the timeline, one per vehicle and period. */
export function gapBands(offline, start, end, nameOf) {
  const span = end - start;
  const bands = [];
  for (const [id, periods] of offline) {
    for (const p of periods) {
      const from = Math.max(p.from, start);
      bands.push(h("span.gap", {
        style: `left:${((from - start) / span) * 100}%;width:${((Math.min(p.to, end) - from) / span) * 100}%`,
        title: `${nameOf(id)} ${offlineText(p)}`,
        dataset: { vehicle: id },
      }));
    }
  }
  return bands;
}
