// The console: log in (session.js), open the live link, and tie the map, the panels and
// the tools together. `window.fleetConsole` holds the pieces (for a look from the
// browser's developer tools, and for the browser tests).

import { alarmText } from "./alarms.js";
import { shapeDiff, zoneName } from "./changes.js";
import { Commands, targetPoints } from "./commands.js";
import { shapeOnTheWay } from "./crossing.js";
import { ControlPanel } from "./control.js";
import { Fleet, TRAIL_MINUTES, commandName, isFinal, topicsOf } from "./fleet.js";
import { MapHolder } from "./holder.js";
import { LiveLink } from "./live.js";
import { FleetTable, VehiclePanel } from "./panels.js";
import { endSession, logOut, startSession } from "./session.js";
import { PHONE, Tabs } from "./tabs.js";
import { dismissTagged, openLog } from "./toasts.js";
import { Tools } from "./tools.js";
import { ago, clock, confirmAction, h, sending, toast, until, zoneText } from "./ui.js";

const $ = (id) => document.getElementById(id);
const REPLAY_RETRY_MS = 3000; // the replay's module not loaded: tried again after this
const namesOf = (vehicles) => vehicles.map((v) => v.view.name || v.id).join(", ");
/** Zones or obstacles drawn, changed or removed since the console last read them, said
 * (a no-go zone appearing over the boats' water came with no word). */
function sayShapes(before, after, key, named) {
  for (const { shape, how } of shapeDiff(before, after, key)) {
    toast(`${named(shape)} ${how === "drawn" ? "drawn on the map" : how}`, "info");
  }
}

/** The console once logged in: ``me`` (from /api/me) decides what it offers. */
class Console {
  constructor(api, me, config, MapView) {
    this.api = api;
    this.me = me;
    this.app = $("app");
    $("stop-all").hidden = me.role === "viewer"; // a viewer reads; every stop needs an operator
    this.fleet = new Fleet();
    this.selection = new Set();
    this.focused = null;
    window.fleetConsole = this;

    // the role gives way on a phone; the name stays whole
    $("who").replaceChildren(me.username, h("span.role", {}, ` · ${me.role}`));
    // Every time shown is this browser's local time: say in which zone, once.
    $("tz").textContent = `times in ${zoneText()}`;
    $("replay-zone").textContent = `24-hour, local time ${zoneText()}, e.g. 2026-11-26 14:05:00`;
    this.map = new MapView($("map"), config, this.fleet, {
      onPick: (id, additive) => this.pick(id, additive),
      onMapClick: (latlng) => this.tools.mapClicked(latlng),
    });
    this.table = new FleetTable(this);
    this.vehiclePanel = new VehiclePanel(this);
    this.controlPanel = new ControlPanel(this);
    this.tabs = new Tabs(this);
    this.commands = new Commands(this); // sent from the bar, the panels and the toasts
    this.tools = new Tools(this); // the bar over the map
    this.holder = new MapHolder(this); // who holds the selected boats, on a phone's map
    $("logout").addEventListener("click", () => sending("logout", () => this.logOut()));
    $("messages").addEventListener("click", openLog); // a toast gone can be read again
    // Replay pressed before its module (loaded below) took the form: not a page reload.
    $("replay-form").addEventListener("submit", (e) => e.preventDefault());

    this.fleet.addEventListener("added", (e) => {
      this.live.subscribe(topicsOf(e.detail.id));
      this.seedTrail(e.detail.id);
    });
    this.fleet.addEventListener("snapshot", () => {
      if (!this.map.fitted) this.map.fitFleet();
    });
    this.fleet.addEventListener("change", (e) => {
      if (e.detail.what === "view" && this.selection.has(e.detail.id)) this.selectionChanged();
    });
    this.fleet.addEventListener("event", (e) => {
      if (e.detail.event.kind === "zones_changed") this.loadShapes(); // a zone of a vehicle
    });
    this.fleet.addEventListener("presence", (e) => this.presenceChanged(e.detail));
    this.fleet.addEventListener("expired", (e) => this.expired(e.detail));
    this.fleet.addEventListener("failed", (e) => this.failed(e.detail));
    this.fleet.addEventListener("alarms", (e) => { // what went wrong, whatever tab is open
      const { id, raised, cleared } = e.detail;
      const name = this.fleet.vehicles.get(id).view.name || id;
      // an alarm that ended takes its toast down (it said the boat was in failsafe after)
      for (const kind of cleared) dismissTagged(`alarm/${id}/${kind}`);
      for (const a of raised) toast(`${name}: ${alarmText(a)}`, "error", null, `alarm/${id}/${a.kind}`);
    });
    this.live = new LiveLink({
      token: api.token,
      pingTopic: `user/${me.username}/console-ping`,
      onEvent: (topic, data, snapshot) => this.onEvent(topic, data, snapshot),
      onState: (state, info) => this.linkState(state, info),
    });
    this.live.subscribe(["fleet", "zones"]);
    this.live.start();
    this.loadShapes();
    this.controlPanel.loadRequests();
    this.controlPanel.draw();
    setInterval(() => this.tick(), 1000);
    this.loadReplay();
  }

  /** The replay's module, loaded after the page; a load that failed (the network gone at
   * that moment: an uncaught error, and no replay for the tab's life) is tried again. */
  loadReplay(attempt = 0) {
    import(attempt ? `./replay.js?attempt=${attempt}` : "./replay.js").then(({ Replay }) => {
      this.replay = new Replay(this);
      this.replay.drawChoices();
      this.fleet.addEventListener("added", () => this.replay.drawChoices());
    }).catch((e) => {
      console.warn("replay:", e.message);
      setTimeout(() => this.loadReplay(attempt + 1), REPLAY_RETRY_MS);
    });
  }

  onEvent(topic, data, snapshot) {
    if (topic === "fleet") return this.fleet.applyFleet(data, snapshot);
    if (topic === "zones") return this.loadShapes(); // drawn or removed: read them again
    const [, id, kind] = topic.split("/");
    if (kind === "telemetry") this.fleet.applyTelemetry(id, data);
    else if (kind === "commands") this.fleet.applyCommands(id, data, snapshot);
    else if (kind === "events") this.fleet.applyEvents(id, data, snapshot);
    else if (kind === "control") this.fleet.applyControl(id, data);
    return undefined;
  }

  linkState(state, info) {
    const link = $("link");
    link.dataset.state = state;
    // Lost until live again: the tries between ("connecting") still show nothing new.
    this.app.dataset.link = state === "connecting" && this.wasLost ? "lost" : state;
    if (state === "live") {
      link.textContent = "live";
      if (this.wasLost) {
        toast("link back: the view is up to date again", "ok");
        for (const id of this.fleet.vehicles.keys()) this.seedTrail(id);
        this.loadShapes();
        this.controlPanel.loadRequests(); // answered, or dropped, meanwhile
      }
      this.wasLost = false;
    } else if (state === "lost") {
      this.wasLost = true;
      this.retryAt = Date.now() + info.retryInMs; // counted down each second (tick)
      this.sayRetry();
    } else if (state === "refused") {
      link.textContent = "refused: log in again";
      endSession(1500);
    } else {
      link.textContent = !this.wasLost ? "connecting…"
        : PHONE.matches ? "link lost · retrying" : "link lost · reconnecting…";
    }
  }

  /** A vehicle that goes offline in the middle of a command is said at once: its map label
   * would otherwise still read "executing". */
  /** Log out, after a word when this user holds control of a boat (it stays theirs): the
   * session ended on the server too (a pasted API token is only forgotten here). */
  async logOut() {
    const held = this.held();
    if (held.length) {
      const names = namesOf(held);
      // what happens to each lease once this console is gone, as it was granted
      const lapsing = held.filter((v) => v.control.operator_timeout_s);
      const kept = held.filter((v) => !v.control.operator_timeout_s);
      const said = [
        kept.length ? `${kept.length === held.length ? "Control" : `Control of ${namesOf(kept)}`} ` +
          "stays yours until it ends, with nobody at this console" : null,
        ...lapsing.map((v) => `control of ${v.view.name || v.id} lapses ` +
          `${v.control.operator_timeout_s} s after your last open console goes quiet, and the boat holds station`),
      ].filter(Boolean).join("; ");
      const ok = await confirmAction({
        title: `Log out while you hold control of ${names}?`,
        text: `${said.charAt(0).toUpperCase()}${said.slice(1)}: release it first if nobody ` +
          "is to command them from here.",
        confirm: "Log out",
      });
      if (!ok) return;
    }
    this.live.stop();
    await this.api.post("/auth/logout", {}).catch(() => null); // gone or refused: forget it
    logOut();
  }

  /** A command that expired unacknowledged, said to whom it concerns: its sender, the
   * boat's managers, and everyone for the server's own (a hold at a lease's end that
   * never reached a boat out of contact). */
  expired({ id, cmd }) {
    const said = this.commandSaid(id, cmd);
    if (!said) return;
    const why = cmd.detail ? ` (${cmd.detail})` : "";
    toast(`${said.what} for ${said.name} expired${why}: the boat never acknowledged it`, "error");
  }

  /** A command that failed on the boat or that it refused, said to the same people (it
   * was shown only in the panels: its sender, on another tab, was not told). */
  failed({ id, cmd }) {
    const said = this.commandSaid(id, cmd);
    if (!said) return;
    const why = cmd.detail ? `: ${cmd.detail.replace(/_/g, " ")}` : ""; // keep_station: words
    const how = cmd.status === "rejected" ? "was refused by the boat" : "failed";
    toast(`${said.what} for ${said.name} ${how}${why}`, "error");
  }

  /** Whom a command's end concerns (its sender, the boat's managers, everyone for the
   * server's own), and how it is named to them; null: not this user. */
  commandSaid(id, cmd) {
    const mine = cmd.issued_by === this.me.username;
    if (!mine && cmd.issued_by !== "system" && !this.controlPanel.managed(id)) return null;
    const name = this.fleet.vehicles.get(id).view.name || id;
    const what = `${cmd.issued_by === "system" ? "the server's " : ""}${cmd.type.replace(/_/g, " ")}`;
    return { name, what };
  }

  presenceChanged({ id, was, now }) {
    if (now === "online" && was === "offline") {
      const v = this.fleet.vehicles.get(id);
      dismissTagged(`offline/${id}`); // "went offline during ..." is stale now
      toast(`${v.view.name || id} is back online`, "ok");
    }
    if (now !== "offline") return;
    const cmd = this.fleet.latestCommand(id);
    if (!cmd || isFinal(cmd.status)) {
      this.sayOffline(id);
      return;
    }
    const v = this.fleet.vehicles.get(id);
    const heard = this.fleet.lastContact(id);
    toast(
      `${v.view.name || id} went offline during ${cmd.type.replace(/_/g, " ")} (${cmd.stage}); ` +
        `last heard ${Number.isFinite(heard) ? clock(heard) : "–"}: what it does now is unknown`,
      "error",
      null,
      `offline/${id}`,
    );
  }

  /** A boat gone out of contact with no mission under way, said whatever tab is open: the
   * boats found offline together (after a server restart, in one snapshot) in one toast. */
  sayOffline(id) {
    if (this.offlineSoon) {
      this.offlineSoon.add(id);
      return;
    }
    this.offlineSoon = new Set([id]);
    setTimeout(() => {
      const ids = [...this.offlineSoon].filter((x) => this.fleet.vehicles.get(x)?.view.presence === "offline");
      this.offlineSoon = null;
      if (!ids.length) return;
      const said = ids.map((x) => {
        const heard = this.fleet.lastContact(x);
        return `${this.fleet.vehicles.get(x).view.name || x} (last heard ${Number.isFinite(heard) ? clock(heard) : "–"})`;
      });
      toast(`out of contact: ${said.join(", ")}`, "warn", null, ids.length === 1 ? `offline/${ids[0]}` : null);
    }, 500);
  }

  /** "link lost · reconnecting in 4 s", as the next try comes nearer. */
  sayRetry(now = Date.now()) {
    const link = $("link");
    if (link.dataset.state !== "lost" || !this.retryAt) return;
    const s = Math.max(0, Math.ceil((this.retryAt - now) / 1000));
    // on a phone short enough for the header's one row
    link.textContent = PHONE.matches ? `link lost · retry ${s} s` : `link lost · reconnecting in ${s} s`;
  }

  /** Once a second: the "ago" and "until" texts move on (no call to the server). */
  tick() {
    const now = Date.now();
    this.sayRetry(now);
    this.keepLeasesAlive(now);
    this.warnLeasesEnding(now);
    for (const el of document.querySelectorAll("[data-since]")) {
      el.textContent = ago(+el.dataset.since, now);
    }
    for (const el of document.querySelectorAll("[data-until]")) {
      el.textContent = `(${until(el.dataset.until, now)})`;
    }
  }

  /** The vehicles whose control this user holds. */
  held() {
    return [...this.fleet.vehicles.values()]
      .filter((v) => v.control && v.control.holder === this.me.username);
  }

  /** A minute before a lease of this user's ends, once: the boat then holds station, and
   * more time is the manager's to grant (a new request). */
  warnLeasesEnding(now) {
    this.warned = this.warned || new Set();
    for (const v of this.held()) {
      const c = v.control;
      if (!c.expires_at) continue;
      const left = Date.parse(c.expires_at) - now;
      const key = `${v.id}@${c.expires_at}`;
      if (left > 60000 || left <= 0 || this.warned.has(key)) continue;
      this.warned.add(key);
      toast(`your control of ${v.view.name || v.id} ends at ${clock(c.expires_at)} ` +
        `(${until(c.expires_at, now)}); then it holds station: ask for more in time`, "warn");
    }
  }

  /**
   * While this user holds control of a vehicle whose lease needs a live client
   * (``operator_timeout_s``), say so: ``POST /client/heartbeat`` at a quarter of the
   * shortest such timeout (at most every second). Closing the console stops it, and the
   * lease lapses: the vehicle holds station.
   */
  keepLeasesAlive(now) {
    const held = this.held().filter((v) => v.control.operator_timeout_s && v.view.instance_id);
    if (!held.length || this.heartbeatBusy) return;
    const every = Math.max(1000, (Math.min(...held.map((v) => v.control.operator_timeout_s)) * 1000) / 4);
    if (now - (this.lastHeartbeat || 0) < every) return;
    this.lastHeartbeat = now;
    this.heartbeatBusy = true;
    this.api.post("/client/heartbeat", { instance_ids: held.map((v) => v.view.instance_id) })
      .catch((e) => console.warn("heartbeat:", e.message))
      .finally(() => { this.heartbeatBusy = false; });
  }

  async seedTrail(id) {
    const from = new Date(Date.now() - TRAIL_MINUTES * 60000).toISOString();
    try {
      const track = await this.api.get(`/api/vehicles/${encodeURIComponent(id)}/track`, {
        from, max_points: 600,
      });
      this.fleet.seedTrail(id, track.points);
    } catch {
      // no trail yet: the live samples draw one
    }
  }

  /** Zones (when the server has them), obstacles. */
  async loadShapes() {
    try {
      const zones = (await this.api.get("/api/zones")).zones || [];
      if (this.liveZones) sayShapes(this.liveZones, zones, "zone_id", zoneName);
      this.liveZones = zones;
      this.sayMissionsCrossed(zones);
      // a replay draws the zones of its time; Back to live draws these
      if (this.app.dataset.replay !== "on") this.map.setZones(this.liveZones);
    } catch (e) {
      if (e.status !== 404) console.warn("zones:", e.message);
    }
    try {
      const obstacles = (await this.api.get("/api/obstacles")).obstacles || [];
      if (this.liveObstacles) sayShapes(this.liveObstacles, obstacles, "obstacle_id", (o) => `obstacle ${o.name}`);
      this.liveObstacles = obstacles;
      // a replay draws the obstacles of its time; Back to live draws these
      if (this.app.dataset.replay !== "on") this.map.setObstacles(this.liveObstacles);
    } catch (e) {
      console.warn("obstacles:", e.message);
    }
  }

  /** A no-go zone drawn or changed across a mission under way, said to the boat's holder
   * and managers (the server checks again only the commands not yet delivered; the boat
   * sailed on into the zone and only its alarm said so). Once per mission and zone. */
  sayMissionsCrossed(zones) {
    const crossed = new Map();
    for (const v of this.fleet.vehicles.values()) {
      const here = v.view.position;
      const held = v.control && v.control.holder === this.me.username;
      if (!here || here.lat == null || !(held || this.controlPanel.managed(v.id))) continue;
      const its = zones.filter((z) => z.kind === "no_go"
        && (!(z.vehicles || []).length || z.vehicles.includes(v.id)));
      for (const cmd of its.length ? this.fleet.recentCommands(v.id) : []) {
        if (isFinal(cmd.status) || !cmd.args) continue;
        const zone = shapeOnTheWay([here, ...targetPoints(cmd.type, cmd.args)], its);
        if (zone) crossed.set(`${cmd.command_id}/${zone.zone_id}`, { v, cmd, zone });
      }
    }
    for (const [key, { v, cmd, zone }] of this.crossed ? crossed : []) {
      if (this.crossed.has(key)) continue;
      toast(`${v.view.name || v.id}'s ${commandName(cmd.type)} under way now runs into no-go zone ` +
        `${zone.name}: stop it, or send it another way`, "error", null, `crossed/${v.id}`);
    }
    this.crossed = crossed;
  }

  // ---- the selection --------------------------------------------------------------------
  /** A vehicle clicked, on the map or in the fleet table: it alone selected, or
   * (``additive``: shift, ctrl or cmd held, or its box ticked) added to the selection or
   * taken out. */
  pick(id, additive) {
    if (additive) {
      if (this.selection.has(id)) this.selection.delete(id);
      else this.selection.add(id);
    } else {
      this.selection = new Set([id]);
    }
    if (this.selection.has(id)) {
      this.focused = id;
      this.vehiclePanel.show(id);
      if (!additive && !PHONE.matches) this.tabs.show("vehicle");
    }
    this.selectionChanged();
  }

  /** The selection changed: the map, the table and the bar over the map say it (and, on
   * a phone, who holds control of it). */
  selectionChanged() {
    this.map.setSelected(this.selection);
    this.table.render();
    this.tools.showFor(this.selection);
    this.holder.render();
  }
}

startSession((api, me, config, MapView) => new Console(api, me, config, MapView));
