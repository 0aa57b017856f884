// The replay's timeline marks what changed on the map itself: a zone drawn, changed or
// removed, an obstacle placed or removed. Each mark is one change of the set (a zone of
// every boat made one event per boat), said in words, and a click moves the cursor there.

import { clock, h } from "./ui.js";

// Changes nearer than this share of the window are one mark (a mark is about 1 % wide).
const GROUPED = 0.01;
const ZONE_KINDS = { no_go: "no-go zone", operating_area: "operating area" };

/** A zone as people read it: "no-go zone reef". */
export function zoneName(z) {
  return `${ZONE_KINDS[z.kind] || "zone"} ${z.name || z.zone_id}`;
}

/** What changed from one set of shapes (zones, obstacles) to the next, told apart by
 * ``key``: ``[{shape, was, how}]``, ``how`` one of drawn, changed, removed (``shape`` the
 * one removed then). */
export function shapeDiff(before, after, key) {
  const was = new Map(before.map((x) => [x[key], x]));
  const now = new Map(after.map((x) => [x[key], x]));
  const out = [];
  for (const [id, x] of now) {
    const old = was.get(id);
    if (!old) out.push({ shape: x, was: null, how: "drawn" });
    else if (JSON.stringify(old) !== JSON.stringify(x)) out.push({ shape: x, was: old, how: "changed" });
  }
  for (const [id, x] of was) if (!now.has(id)) out.push({ shape: x, was: x, how: "removed" });
  return out;
}

/** What each change of the zones did, from the sets before and after it (the replay's
 * frames, ``[{t, zones}]``, the first the set at the window's start): ``[{t, text}]``. */
export function zoneChanges(frames) {
  const out = [];
  for (let i = 1; i < (frames || []).length; i += 1) {
    const said = shapeDiff(frames[i - 1].zones, frames[i].zones, "zone_id").map(({ shape, was, how }) =>
      `${zoneName(shape)} ${how}${how === "changed" && was.name !== shape.name ? ` (was ${was.name})` : ""}`);
    out.push({ t: frames[i].t, kind: "zone", text: said.join("; ") || "zones changed" });
  }
  return out;
}

/** The obstacles placed and removed within the window (``[{t0, t1, obstacle}]``). */
export function obstacleChanges(obstacles, start, end) {
  const out = [];
  const within = (t) => t > start && t <= end;
  for (const { t0, t1, obstacle } of obstacles || []) {
    const name = `obstacle ${obstacle.name || obstacle.obstacle_id}`;
    if (within(t0)) out.push({ t: t0, kind: "obstacle", text: `${name} placed` });
    if (within(t1)) out.push({ t: t1, kind: "obstacle", text: `${name} removed` });
  }
  return out;
}

/** The marks on a timeline from ``start`` to ``end``; a click moves the cursor (``seek(t)``,
 * ``cursor()``) to the mark's change. Changes closer than a mark's width are one mark: it
 * says each of them, and each click goes to the next of them (from the first). */
export function changeMarks(changes, start, end, seek, cursor) {
  const span = end - start;
  const groups = [];
  for (const c of [...changes].sort((a, b) => a.t - b.t)) {
    const last = groups[groups.length - 1];
    if (last && (c.t - last[0].t) / span < GROUPED) last.push(c);
    else groups.push([c]);
  }
  return groups.map((group) => {
    const times = group.map((c) => c.t);
    const said = group.map((c) => `${clock(c.t)} ${c.text}`).join("\n");
    const kinds = new Set(group.map((c) => c.kind));
    const title = group.length > 1 ? `${said}\n(each click: the next of these)` : said;
    return h(`button.change-mark.c-${kinds.size === 1 ? group[0].kind : "mixed"}`, {
      type: "button",
      style: `left:${((times[0] - start) / span) * 100}%`,
      title,
      "aria-label": said,
      dataset: { t: times[0], count: group.length },
      onclick: () => {
        const now = cursor();
        const inside = now >= times[0] && now < times[times.length - 1];
        seek(inside ? times.find((t) => t > now) : times[0]);
      },
    });
  });
}
