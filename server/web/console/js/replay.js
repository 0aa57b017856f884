// Replay: the stored tracks of the chosen vehicles over a window, played in sync on a
// timeline that also holds their commands, grants and events (each lights up as the
// cursor passes it); the window exports as GPX or GeoJSON (export.js).

import { changeMarks, obstacleChanges, zoneChanges } from "./changes.js";
import { exportWindow } from "./export.js";
import { drawTrack, gapBands, offlinePeriods, offlineText, periodAt } from "./gaps.js";
import { placeLabels } from "./labels.js";
import { L, colourOf, escapeHtml } from "./map.js";
import { describeEvent, eventTitle, kindName } from "./describe.js";
import { commandFromEvents } from "./fleet.js";
import { ReplayForm } from "./replayform.js";
import { clock, counted, dateTime, h, sending, toast } from "./ui.js";
import { at as drawnAt, lonStep } from "./wrap.js";

const MAX_EVENTS_PER_VEHICLE = 100000;
const MAX_POINTS_PER_VEHICLE = 50000; // five pages of the track route
const MAX_ZONE_FRAMES = 200; // the zones read again at most this often in one window
const HOLD_GAP_MS = 30000; // samples further apart than this: the marker waits, not glides
const FLASH_MS = 1500;

/** The index of the last point at or before ``t`` (-1 if none): points sorted by t. */
export function lastAtOrBefore(points, t) {
  let lo = 0;
  let hi = points.length - 1;
  let found = -1;
  while (lo <= hi) {
    const mid = (lo + hi) >> 1;
    if (points[mid].t <= t) {
      found = mid;
      lo = mid + 1;
    } else {
      hi = mid - 1;
    }
  }
  return found;
}

/** Where a vehicle was at ``t``: a stored sample, or between two (linearly, heading the
 * short way round) when they are close in time. Null before its first sample. */
export function positionAt(points, t) {
  const i = lastAtOrBefore(points, t);
  if (i < 0) return null;
  const a = points[i];
  const b = points[i + 1];
  if (!b || a.t === t || b.t - a.t > HOLD_GAP_MS) return { ...a, exact: a.t === t };
  const f = (t - a.t) / (b.t - a.t);
  const ha = a.heading_deg ?? 0;
  const hb = b.heading_deg ?? ha;
  const turn = ((hb - ha + 540) % 360) - 180;
  return {
    t,
    lat: a.lat + (b.lat - a.lat) * f,
    lon: a.lon + lonStep(a.lon, b.lon) * f, // the short way round, across 180 too
    heading_deg: (ha + turn * f + 360) % 360,
    exact: false,
  };
}

export class Replay {
  constructor(ctx) {
    this.ctx = ctx;
    this.map = ctx.map;
    this.form = document.getElementById("replay-form");
    this.choice = new ReplayForm(ctx); // the vehicles and the window
    this.choice.onChange = () => this.forget(); // the form changed: the answer is not its
    this.slider = document.getElementById("replay-slider");
    this.bar = document.getElementById("replay-bar");
    this.playButton = document.getElementById("replay-play");
    this.speed = document.getElementById("replay-speed");
    this.timeOut = document.getElementById("replay-time");
    this.statusOut = document.getElementById("replay-status");
    this.gaps = document.getElementById("timeline-gaps");
    this.ticks = document.getElementById("timeline-ticks");
    this.changes = document.getElementById("timeline-changes");
    this.list = document.getElementById("replay-events");
    this.info = document.getElementById("replay-info");
    this.exportBox = document.getElementById("replay-export");
    this.layer = L.featureGroup();
    this.tracks = new Map();
    this.events = [];
    this.missing = [];
    this.playing = false;
    this.cursor = 0;

    this.form.addEventListener("submit", (e) => {
      e.preventDefault();
      sending("replay", () => this.load());
    });
    this.slider.addEventListener("input", () => this.seek(this.start + +this.slider.value));
    this.map.map.on("zoomend moveend resize", () => {
      if (this.ctx.app.dataset.replay === "on") this.placeLabels();
    });
    this.playButton.addEventListener("click", () => (this.playing ? this.pause() : this.play()));
    document.getElementById("replay-exit").addEventListener("click", () => this.exit());
    for (const b of this.exportBox.querySelectorAll("[data-format]")) {
      const format = b.dataset.format;
      b.addEventListener("click", () => sending(`export/${format}`,
        () => exportWindow(this.ctx, this.ids, this.start, this.end, format)));
    }
  }

  /** The vehicles offered again (one has appeared). */
  drawChoices() {
    this.choice.drawChoices();
  }

  /** The Replay tab opens: its window brought up to now (unless typed). */
  opened() {
    this.choice.opened();
  }

  nameOf(id) {
    const v = this.ctx.fleet.vehicles.get(id);
    return (v && v.view.name) || id;
  }

  async load() {
    const ids = this.choice.chosen();
    const { start, end, error } = this.choice.window();
    // a form refused: said under it, in place of what an earlier replay said there
    if (!ids.length) return this.refuse("choose at least one vehicle");
    if (error) return this.refuse(error);
    if (!(start < end)) return this.refuse("the window must start before it ends");
    // a new replay asked: the one before leaves the map, its events and its export (an
    // empty answer left them, and Export saved the old window)
    this.clear();
    this.info.textContent = "loading…";
    let got;
    let zoneFrames = null;
    let obstacles = null;
    try {
      got = await Promise.all(ids.map((id) => this.fetchVehicle(id, start, end)));
      zoneFrames = await this.fetchZones(start, end).catch((e) => {
        console.warn("replay zones:", e.message); // the zones of now stay, said so
        return null;
      });
      obstacles = await this.fetchObstacles(start, end).catch((e) => {
        console.warn("replay obstacles:", e.message); // those of now stay, said so
        return null;
      });
    } catch (e) {
      this.info.textContent = "";
      return toast(`replay: ${e.message}`, "error");
    }
    const total = got.reduce((n, g) => n + g.points.length, 0);
    if (!total && !got.some((g) => g.events.length)) { // nothing to play: said; the map stays
      this.info.textContent = `Nothing was recorded for ${ids.length === 1 ? "this vehicle" : "these vehicles"} ` +
        `from ${dateTime(start)} to ${dateTime(end)}: no position, no event. ` +
        "Try a wider window (1 h, 6 h, or an earlier start).";
      this.choice.hold();
      return undefined;
    }
    this.start = start;
    this.end = end;
    this.ids = ids;
    this.zoneFrames = zoneFrames;
    this.obstaclesThen = obstacles;
    this.obstaclesDrawn = null;
    this.tracks = new Map(got.map((g) => [g.id, g.points]));
    this.events = got.flatMap((g) => g.events).sort((a, b) => a.t - b.t);
    this.offline = new Map(got.map((g) => [g.id, offlinePeriods(g.events, g.points, start, end)]));
    // a boat ticked with no position in the window: said, not left off the map unsaid
    this.missing = got.filter((g) => !g.points.length).map((g) => this.noPositions(g.id, start));
    this.info.replaceChildren(
      `${counted(ids.length, "vehicle")}, ${counted(total, "stored position")}, ` +
        `${counted(this.events.length, "event")}, ${dateTime(start)} to ${dateTime(end)}`,
      ...this.missing.map((text) => h("div.no-positions", {}, text)),
      ...zonesSaid(zoneFrames, this.events),
      ...obstaclesSaid(obstacles, start, end),
    );
    this.choice.hold();
    this.enter();
  }

  /** "H2OmniX Bravo: no positions in this window (offline since 20:46:11)": a vehicle
   * ticked that has none, with when it was last heard if that was before the window. */
  noPositions(id, start) {
    const v = this.ctx.fleet.vehicles.get(id);
    const heard = this.ctx.fleet.lastContact(id);
    const presence = v ? v.view.presence : null;
    let when = "";
    if (Number.isFinite(heard) && heard < start) {
      const at = start - heard < 86400000 ? clock(heard) : dateTime(heard);
      when = presence && presence !== "online" ? ` (${presence} since ${at})` : ` (last heard ${at})`;
    }
    return `${this.nameOf(id)}: no positions in this window${when}`;
  }

  /** The replay shown before, gone: its layers, events, timeline and export. */
  clear() {
    this.pause();
    if (this.ctx.app.dataset.replay === "on") this.exit();
    this.layer.clearLayers();
    this.markers = new Map();
    this.tracks = new Map();
    this.events = [];
    this.offline = new Map();
    this.missing = [];
    this.zoneFrames = null;
    this.ids = null;
    this.list.replaceChildren();
    this.list.hidden = false;
    this.ticks.replaceChildren();
    this.changes.replaceChildren();
    this.gaps.replaceChildren();
    this.exportBox.hidden = true;
    this.choice.hold(false);
  }

  /** The form changed: what was read for it before (the summary, the events, Export) is
   * taken from under it. A replay on the map plays on, with its own bar, until another is
   * read or Back to live. */
  forget() {
    this.info.textContent = "";
    this.exportBox.hidden = true;
    this.list.hidden = true;
  }

  refuse(why) {
    this.info.textContent = `${why}: nothing read`;
    toast(why, "error");
  }

  async fetchVehicle(id, start, end) {
    const api = this.ctx.api;
    const points = [];
    let from = new Date(start).toISOString();
    const to = new Date(end).toISOString();
    while (from && points.length < MAX_POINTS_PER_VEHICLE) {
      const page = await api.get(`/api/vehicles/${encodeURIComponent(id)}/track`, { from, to });
      for (const p of page.points) points.push({ ...p, t: Date.parse(p.ts) });
      from = page.truncated ? page.next_from : null;
    }
    const events = [];
    let after = null;
    do {
      const query = { vehicle_id: id, from: new Date(start).toISOString(), to, limit: 10000 };
      const page = await api.get("/api/events", after ? { ...query, after } : query);
      events.push(...page.events);
      after = page.next_after;
    } while (after && events.length < MAX_EVENTS_PER_VEHICLE);
    return {
      id,
      points,
      events: events.map((e) => ({ ...e, t: Date.parse(e.at), vehicle: id })),
    };
  }

  /** The zones as they were at the window's start, and again after each change in it
   * (``/api/zones/changes``, then ``/api/zones?at=``): ``[{t, zones}]`` in time order. */
  async fetchZones(start, end) {
    const api = this.ctx.api;
    const iso = (t) => new Date(t).toISOString();
    const frames = [{ t: start, zones: (await api.get("/api/zones", { at: iso(start) })).zones || [] }];
    // the changes of the zones this user sees (a zone for every vehicle too): their times
    const query = { from: iso(start), to: iso(end) };
    const first = new Map(); // each version once: its time
    for (const c of (await api.get("/api/zones/changes", query)).changes) {
      if (!first.has(c.version)) first.set(c.version, Date.parse(c.at));
    }
    const times = [...first.values()].sort((a, b) => a - b).slice(0, MAX_ZONE_FRAMES);
    for (const t of times) {
      frames.push({ t, zones: (await api.get("/api/zones", { at: iso(t) })).zones || [] });
    }
    return frames;
  }

  /** Every obstacle there was at some time of the window, each with ``created_at`` and
   * ``deleted_at`` (null: still there): ``[{t0, t1, obstacle}]``. */
  async fetchObstacles(start, end) {
    const iso = (t) => new Date(t).toISOString();
    const got = await this.ctx.api.get("/api/obstacles", { from: iso(start), to: iso(end) });
    return (got.obstacles || []).map((o) => ({
      t0: Date.parse(o.created_at),
      t1: o.deleted_at ? Date.parse(o.deleted_at) : Infinity,
      obstacle: o,
    }));
  }

  /** The obstacles of the cursor's time on the map (drawn again only when they change). */
  drawObstacles() {
    if (!this.obstaclesThen) return;
    const now = this.obstaclesThen.filter((o) => o.t0 <= this.cursor && this.cursor < o.t1);
    const key = now.map((o) => o.obstacle.obstacle_id).join(",");
    if (key === this.obstaclesDrawn) return;
    this.obstaclesDrawn = key;
    this.map.setObstacles(now.map((o) => o.obstacle));
  }

  /** The zones of the cursor's time on the map (drawn again only when they change). */
  drawZones() {
    if (!this.zoneFrames) return;
    let frame = this.zoneFrames[0];
    for (const f of this.zoneFrames) if (f.t <= this.cursor) frame = f;
    if (frame === this.zoneFrame) return;
    this.zoneFrame = frame;
    this.map.setZones(frame.zones);
  }

  enter() {
    if (this.ctx.app.dataset.replay !== "on") {
      // The live view as it was (a replay of another window keeps the first's): Back to
      // live returns to it, not to wherever the replay's tracks took the map.
      this.liveView = { center: this.map.map.getCenter(), zoom: this.map.map.getZoom() };
    }
    this.map.showLive(false);
    this.layer.clearLayers();
    this.layer.addTo(this.map.map);
    this.markers = new Map();
    const bounds = [];
    for (const id of this.ids) {
      const v = this.ctx.fleet.vehicles.get(id);
      const colour = colourOf(v ? v.index : 0);
      const pts = this.tracks.get(id).map(drawnAt);
      bounds.push(...pts);
      drawTrack(this.layer, id, this.tracks.get(id), this.offline.get(id), colour);
      const marker = L.marker(pts[0] || [0, 0], {
        icon: L.divIcon({
          className: "vicon replay",
          html: `<svg class="arrow" viewBox="-13 -13 26 26"><circle class="halo" r="12"></circle>
            <path d="M0,-10 L7,8 L0,4 L-7,8 Z"></path></svg>
            <div class="vlabel" style="left:28px;top:4px"><b>${escapeHtml((v && v.view.name) || id)}</b></div>`,
          iconSize: [26, 26],
          iconAnchor: [13, 13],
        }),
        interactive: false,
      });
      this.markers.set(id, marker);
    }
    if (bounds.length) {
      this.map.map.fitBounds(L.latLngBounds(bounds).pad(0.3), { maxZoom: 19, animate: false });
    }
    this.slider.max = String(this.end - this.start);
    this.slider.step = String(Math.max(100, Math.round((this.end - this.start) / 2000 / 100) * 100));
    this.drawTimeline();
    this.bar.hidden = false;
    this.exportBox.hidden = false;
    document.getElementById("actions").hidden = true;
    this.ctx.app.dataset.replay = "on";
    this.map.map.invalidateSize(false);
    this.seek(this.start);
  }

  exit() {
    this.pause();
    this.map.map.removeLayer(this.layer);
    this.map.showLive(true);
    this.bar.hidden = true;
    delete this.ctx.app.dataset.replay;
    if (this.zoneFrame) this.map.setZones(this.ctx.liveZones || []); // the zones of now
    this.zoneFrame = null;
    if (this.obstaclesDrawn != null) this.map.setObstacles(this.ctx.liveObstacles || []);
    this.obstaclesDrawn = null;
    this.ctx.selectionChanged();
    this.map.map.invalidateSize(false);
    if (this.liveView) {
      this.map.map.setView(this.liveView.center, this.liveView.zoom, { animate: false });
      this.liveView = null;
    }
  }

  drawTimeline() {
    const span = this.end - this.start;
    const known = (id) => commandFromEvents(this.events, id); // a superseding command, by its events
    this.ticks.replaceChildren(...this.events.map((e, i) => h(`span.tick.k-${e.kind.split("_")[0]}`, {
      style: `left:${((e.t - this.start) / span) * 100}%`,
      title: `${clock(e.t)} ${this.nameOf(e.vehicle)} ${kindName(e.kind)} ${describeEvent(e, known)}`,
      dataset: { index: i },
      onclick: () => this.seek(e.t), // as its line in the list does
    })));
    this.gaps.replaceChildren(...gapBands(this.offline, this.start, this.end, (id) => this.nameOf(id)));
    // what changed on the map itself: each change once, whichever boats it concerned
    const changes = [...zoneChanges(this.zoneFrames), ...obstacleChanges(this.obstaclesThen, this.start, this.end)];
    this.changes.replaceChildren(...changeMarks(changes, this.start, this.end, (t) => this.seek(t), () => this.cursor));
    this.list.replaceChildren(...this.events.map((e, i) => h("li", {
      dataset: { index: i, kind: e.kind },
      title: eventTitle(e),
      onclick: () => this.seek(e.t),
    },
    h("time", {}, clock(e.t)), " ", h("b", {}, this.nameOf(e.vehicle)), " ",
    kindName(e.kind), " ", describeEvent(e, known))));
  }

  /** Move the cursor to ``t``: every chosen vehicle where its track puts it then. */
  seek(t) {
    const before = this.cursor;
    this.cursor = Math.min(Math.max(t, this.start), this.end);
    this.slider.value = String(this.cursor - this.start);
    this.timeOut.value = `${dateTime(this.cursor)}`;
    this.drawZones();
    this.drawObstacles();
    const away = [];
    for (const [id, marker] of this.markers) {
      const points = this.tracks.get(id);
      const gap = periodAt(this.offline.get(id), this.cursor);
      if (gap) away.push(`${this.nameOf(id)} ${offlineText(gap)}`);
      // before its first stored position a vehicle waits, faded, where that one will be;
      // out of contact, greyed where it was last heard (never gliding across the gap)
      const last = points[lastAtOrBefore(points, this.cursor)];
      const at = (gap && last && { ...last, exact: last.t === this.cursor })
        || positionAt(points, this.cursor) || (points[0] && { ...points[0], before: true });
      if (!at) {
        if (this.layer.hasLayer(marker)) this.layer.removeLayer(marker);
        continue;
      }
      marker.setLatLng(drawnAt(at));
      if (!this.layer.hasLayer(marker)) marker.addTo(this.layer);
      const el = marker.getElement();
      if (el) {
        el.dataset.vehicle = id;
        el.dataset.lat = at.lat;
        el.dataset.lon = at.lon;
        el.dataset.exact = at.exact ? "true" : "false";
        el.classList.toggle("before-first", Boolean(at.before));
        el.classList.toggle("offline", Boolean(gap));
        el.querySelector("path").setAttribute("transform", `rotate(${at.heading_deg ?? 0})`);
      }
    }
    const said = [...this.missing, ...away];
    this.statusOut.value = said.join("; ");
    this.statusOut.hidden = !said.length;
    this.markEvents(before, this.cursor);
    this.placeLabels();
  }

  /** The replay's labels placed as the live ones are (labels.js): each on the side of its
   * marker that is free and on the map (on a phone they ran off its right edge). */
  placeLabels() {
    const anchors = [];
    const labels = new Map();
    for (const [id, marker] of this.markers || []) {
      const el = this.layer.hasLayer(marker) && marker.getElement();
      const label = el && el.querySelector(".vlabel");
      if (!label || !label.offsetWidth) continue;
      const pt = this.map.map.latLngToContainerPoint(marker.getLatLng());
      anchors.push({ id, x: pt.x, y: pt.y, w: label.offsetWidth, h: label.offsetHeight });
      labels.set(id, label);
    }
    const size = this.map.map.getSize();
    for (const [id, { dx, dy }] of placeLabels(anchors, 13, { w: size.x, h: size.y })) {
      labels.get(id).style.left = `${13 + dx}px`;
      labels.get(id).style.top = `${13 + dy}px`;
    }
  }

  /** Events up to the cursor are passed; those the cursor just went over while playing
   * light up. A jump (the slider, a click) lights only the newest it went over: every
   * tick of an hour lit at once said nothing. */
  markEvents(before, now) {
    const rows = this.list.children;
    const ticks = this.ticks.children;
    let latest = null;
    const hits = [];
    this.events.forEach((e, i) => {
      const passed = e.t <= now;
      rows[i].classList.toggle("passed", passed);
      ticks[i].classList.toggle("passed", passed);
      if (passed) latest = i;
      if (now > before && e.t > before && e.t <= now) hits.push(i); // passed going forward
    });
    for (const i of this.playing ? hits : hits.slice(-1)) {
      for (const el of [rows[i], ticks[i]]) {
        el.classList.add("hit");
        clearTimeout(el.hitTimer);
        el.hitTimer = setTimeout(() => el.classList.remove("hit"), FLASH_MS);
      }
    }
    for (const r of this.list.querySelectorAll(".current")) r.classList.remove("current");
    if (latest !== null) {
      rows[latest].classList.add("current");
      if (this.playing) rows[latest].scrollIntoView({ block: "nearest" });
    }
  }

  play() {
    if (this.cursor >= this.end) this.seek(this.start);
    this.playing = true;
    this.playButton.textContent = "Pause";
    this.playButton.setAttribute("aria-label", "pause");
    let last = performance.now();
    const step = (now) => {
      if (!this.playing) return;
      const dt = (now - last) * +this.speed.value;
      last = now;
      this.seek(this.cursor + dt);
      if (this.cursor >= this.end) return this.pause();
      this.frame = requestAnimationFrame(step);
    };
    this.frame = requestAnimationFrame(step);
  }

  pause() {
    this.playing = false;
    cancelAnimationFrame(this.frame);
    this.playButton.textContent = "Play";
    this.playButton.setAttribute("aria-label", "play");
  }
}

/** What the summary says of the obstacles: those of the cursor's time are drawn (the
 * window's changes counted); when they could not be read, those of now are, said. */
function obstaclesSaid(obstacles, start, end) {
  if (!obstacles) return [h("div.obstacles-now", {}, "Obstacles are drawn as they are now, not as they were then.")];
  const changes = obstacles.filter((o) => o.t0 > start && o.t0 <= end).length +
    obstacles.filter((o) => o.t1 > start && o.t1 <= end).length;
  if (!changes) return [];
  return [h("div.obstacles-then", {}, "Obstacles are drawn as they were at the cursor's time: " +
    `${counted(changes, "obstacle change")} in this window.`)];
}

/** What the summary says of the zones: those of the cursor's time are drawn (counted
 * when the window has changes); when they could not be read, the zones of now are, said. */
function zonesSaid(frames, events) {
  if (!frames) {
    const changes = new Set(events.filter((e) => e.kind === "zones_changed") // one per boat listed
      .map((e) => `${e.data && e.data.zone_id}/${e.data && e.data.version}`)).size;
    const said = "Zones are drawn as they are now, not as they were then";
    return [h("div.zones-now", {}, changes ? `${said}: ${counted(changes, "zone change")} in this window.` : `${said}.`)];
  }
  const changes = frames.length - 1;
  if (!changes) return [];
  return [h("div.zones-then", {}, `Zones are drawn as they were at the cursor's time: ${counted(changes, "zone change")} in this window.`)];
}
